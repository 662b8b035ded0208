"""``creference import label-studio …`` and ``creference import cvat …``: annotation-tool exports →
one ``creference-scene/2`` file per photo (a Label Studio image, whatever its number of tasks, or
a CVAT image), holding all its targets (docs/import.md).

A task or image that cannot be converted is reported on standard error with the task or image
and the region, and skipped; the others are written, each file atomically. The exit status is 2
when anything was skipped for an error, else 0.
"""

from __future__ import annotations

import argparse
import json
import sys
import zipfile
import zlib
from pathlib import Path

from .main import EXIT_INVALID, UsageError, usage_errors

__all__ = ["register"]

def register(subparsers) -> None:
    p = subparsers.add_parser("import", help="convert Label Studio or CVAT exports to scene files",
                              description="Convert the annotations of a Label Studio or CVAT project "
                                          "to scene files (creference-scene/2), one per photo holding "
                                          "all its targets.")
    sub = p.add_subparsers(dest="tool", required=True, metavar="TOOL",
                           help="the annotation tool the export comes from: label-studio or cvat")

    ls = sub.add_parser("label-studio", help="a Label Studio JSON export → one scene per image",
                        description="Convert a Label Studio JSON export (tasks with annotations) to "
                                    "scene files, one per image: the tasks of one image make one scene "
                                    "holding the targets of all of them.")
    ls.add_argument("export", nargs="?", metavar="EXPORT.json", help="the JSON export")
    ls.add_argument("--print-config", action="store_true",
                    help="print the labelling config for a new project and exit")
    ls.add_argument("--lines", choices=["keypoints", "vectors"], default="keypoints",
                    help="with --print-config: draw targets, reference lines and the horizon as keypoints "
                         "(every version; default) or as lines (recent versions with <VectorLabels>, "
                         "checked with 1.23.2)")
    ls.add_argument("--frame", action="store_true", help=argparse.SUPPRESS)  # deprecated: the one config
    ls.add_argument("--users", metavar="USERS.json",
                    help="name workers by the users in this file (the JSON of GET /api/users) "
                         "instead of by user id")
    _common(ls)
    ls.set_defaults(func=_run_label_studio)

    cv = sub.add_parser("cvat", help="a CVAT for images 1.1 export → one scene per image",
                        description="Convert a CVAT for images 1.1 export (annotations.xml, or the "
                                    "ZIP holding it) to scene files, one per image holding all its targets.")
    cv.add_argument("export", nargs="?", metavar="annotations.xml", help="the XML file or the ZIP")
    cv.add_argument("--print-labels", action="store_true",
                    help="print the label specification (for CVAT's Raw label editor) and exit")
    _common(cv)
    cv.set_defaults(func=_run_cvat)


def _common(p) -> None:
    p.add_argument("--out", metavar="DIR", help="folder for the scene files (created if needed)")
    p.add_argument("--image-dir", metavar="DIR",
                   help="folder holding the images: sets each scene's image.path (the image is looked for "
                        "under its name in the export, then by its file name; a note says when it is not there)")
    p.add_argument("--targets", metavar="TARGETS.csv",
                   help="known target sizes and focal lengths: CSV with target_id,length_m,width_m,height_m "
                        "[,focal_length_px][,image] (a row with an image applies to that image only)")
    p.add_argument("--frames", action="store_true", help=argparse.SUPPRESS)  # deprecated: what every import does
    p.add_argument("--classes", metavar="CLASSES.json",
                   help="size priors of your own classes (docs/overview.md, Class size priors) for targets without a size, "
                        "written into the scenes whose targets use them")
    p.add_argument("--overwrite", action="store_true",
                   help="replace a scene file already in --out that differs from what the import writes "
                        "(edited by hand, say); without it such a file is kept and its scene refused")
    p.add_argument("--quiet", action="store_true", help="print nothing but errors")


def _deprecated(args, flag: str, what: str) -> None:
    if getattr(args, flag.strip("-"), False) and not args.quiet:
        print(f"note: {flag} is deprecated and does nothing: {what}", file=sys.stderr)


def _prepare(args):
    from ..io.annotation_tools import ConversionError, load_target_table
    from .estimate import load_classes

    _deprecated(args, "--frames", "every task / image imports as one creference-scene/2 file, whatever its "
                                  "number of targets")
    if args.export is None:
        raise UsageError(f"import {args.tool}: give the export file (see --help)")
    if not args.out:
        raise UsageError(f"import {args.tool}: --out DIR is required")
    if args.image_dir is not None and not Path(args.image_dir).is_dir():
        raise UsageError(f"--image-dir: {args.image_dir!r} is not a folder")
    with usage_errors("--targets: ", ConversionError):
        table = load_target_table(args.targets) if args.targets else None
    return table, load_classes(args.classes)


def _run_label_studio(args) -> int:
    from ..io.annotation_tools import ConversionError
    from ..io.labelstudio import label_studio_config, read_export, read_users, scenes_from_label_studio

    _deprecated(args, "--frame", "the shipped configs hold any number of targets per task")
    if args.print_config:
        sys.stdout.write(label_studio_config(args.lines))
        return 0
    targets, classes = _prepare(args)
    with usage_errors(types=ConversionError):
        users = read_users(args.users) if args.users else None
        report = scenes_from_label_studio(read_export(args.export), image_dir=args.image_dir,
                                          out_dir=args.out, targets=targets, users=users, classes=classes)
    return _finish(report, args)


def _read_cvat(path: str):
    """The parsed annotations.xml of a CVAT export: the XML file, or the ZIP holding it (a missing,
    unreadable or broken file is a ConversionError naming it)."""
    from ..io.annotation_tools import ConversionError, open_input
    from ..io.cvat import MAX_XML_BYTES, read_cvat_xml

    with open_input(path) as f:
        is_zip = zipfile.is_zipfile(f)
        if not is_zip:
            if path.lower().endswith(".zip"):
                raise ConversionError(path, "not a ZIP file (expected CVAT's task export, "
                                            "\"CVAT for images 1.1\", or its annotations.xml)")
        else:
            try:
                with zipfile.ZipFile(f) as z:
                    names = [n for n in z.namelist() if n.rsplit("/", 1)[-1] == "annotations.xml"]
                    if len(names) != 1:
                        raise ConversionError(path, f"expected one annotations.xml in the ZIP, found {len(names)}")
                    info = z.getinfo(names[0])
                    if info.file_size > MAX_XML_BYTES:
                        raise ConversionError(path, f"{names[0]} unpacks to {info.file_size} bytes, more than "
                                                    f"{MAX_XML_BYTES >> 20} MiB; refused (a CVAT export of "
                                                    "thousands of images is a few tens of MB)")
                    data = z.read(info)
            except (zipfile.BadZipFile, zlib.error, EOFError, RuntimeError, NotImplementedError, OSError) as exc:
                raise ConversionError(path, f"cannot read the ZIP: {exc}") from None
    return read_cvat_xml(data, name=f"{path}: {names[0]}") if is_zip else read_cvat_xml(path)


def _run_cvat(args) -> int:
    from ..io.annotation_tools import ConversionError
    from ..io.cvat import cvat_label_spec, scenes_from_cvat

    if args.print_labels:
        print(json.dumps(cvat_label_spec(), indent=2))
        return 0
    targets, classes = _prepare(args)
    with usage_errors(types=ConversionError):
        report = scenes_from_cvat(_read_cvat(args.export), image_dir=args.image_dir,
                                  out_dir=args.out, targets=targets, classes=classes)
    return _finish(report, args)


def _finish(report, args) -> int:
    from ..io.annotation_tools import write_scenes

    for note in report.notes:
        if not args.quiet:
            print(f"note: {note}", file=sys.stderr)
    for err in report.errors:
        print(f"error: {err}", file=sys.stderr)
    done, refused = write_scenes(report.scenes, args.out, overwrite=args.overwrite)
    for err in refused:
        print(f"error: {err}", file=sys.stderr)
    if not args.quiet:
        for scene, path, how in done:
            print(f"{how} {path} ({scene.source})")
        errors = len(report.errors) + len(refused)
        skipped = (f", {errors} skipped for errors" if errors else "") + \
            (f", {report.unannotated} with nothing annotated yet skipped" if report.unannotated else "")
        replaced = sum(how == "replaced" for *_, how in done)
        print(f"{len(done)} scene(s) written to {args.out}{f' ({replaced} replaced)' if replaced else ''}{skipped}")
    return EXIT_INVALID if report.errors or refused else 0

"""``creference plot RESULT.json [--scene SCENE] [--out DIR]``: the figures of an estimate of any scene
(:func:`~creference_bayes.vision.plotting.scene_figures`), from the draws the result keeps, else the
Laplace approximation at its MAP. The scene must be the one the result was estimated from (the same
target ids, image size and content hash), else a one-line error (exit 2).
"""

from __future__ import annotations

import sys
import warnings
from pathlib import Path

from .main import UsageError, usage_errors

__all__ = ["register", "find_scene", "check_result"]


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "plot", help="plot a result: the boxes on the photo, the top view, pair and rank plots; or a batch's data set",
        description="Draw the figures of a result: boxes (the MAP and posterior boxes of every object over "
                    "the photo or a blank canvas), top_view (the ground seen from above, with a zoom on each "
                    "small object; zooms, a figure of their own, when there are many), pairs (the camera and "
                    "the chosen objects) and ranks (the posterior's chains). A result without posterior draws "
                    "shows the Laplace approximation at its MAP, and has no rank plot. A batch's folder gives "
                    "dataset (what each frame read of the quantities its frames share, against the pool the batch "
                    "handed back). See docs/user_guide.md and docs/batch.md.")
    p.add_argument("result", metavar="RESULT.json",
                   help="a creference-result/2 file written by `creference estimate --out` or `creference batch` "
                        "(or a creference-result/1 of an older version); or a batch's folder (or its batch.json): "
                        "the data set's figure, each frame's reading of what the frames share against the pool")
    p.add_argument("--scene", metavar="SCENE.json",
                   help="the scene the result was estimated from (default: the result's scene "
                        "name, looked up next to the result, in the current directory, then among "
                        "the shipped scenes); a different scene is refused")
    p.add_argument("--object", metavar="ID", action="append", default=None,
                   help="an object whose posterior the pair and rank plots show with the camera's (repeat for "
                        "several; default: the first)")
    p.add_argument("--out", metavar="DIR", default=".", help="output directory (default: .)")
    p.add_argument("--format", default="png", choices=["png", "pdf", "svg"],
                   help="file format of the figures (default: %(default)s)")
    p.add_argument("--dpi", type=int, default=110, help="resolution of PNG files (default: %(default)s)")
    p.add_argument("--quiet", action="store_true", help="print nothing but errors")
    p.set_defaults(func=_run)


def find_scene(result: dict, result_path: Path, explicit: str | None):
    """The scene a result (either format) was estimated from (:func:`creference_bayes.io.result.find_scene`),
    its failures as one-line usage errors."""
    from ..io.result import find_scene as _find

    notes: list[str] = []
    with usage_errors():
        scene = _find(result, result_path, explicit, notes)
    for note in notes:  # a scene of the result's name that is another photo's, passed over
        print(f"warning: {note}", file=sys.stderr)
    if result.get("format") == "creference-result/1" and "batch" not in result:
        print("warning: a creference-result/1 (written by an older version): only its target id and image size "
              "were checked against the scene", file=sys.stderr)
    return scene


def check_result(result: dict, path: Path) -> None:
    """A one-line error naming the first key a ``creference-result/2`` lacks (``objects[0].map.x``, …)."""
    from ..models.contract import CAMERA_NAMES, OBJECT_NAMES

    def need(obj, key, where, kind=dict):
        value = obj.get(key) if isinstance(obj, dict) else None
        if not isinstance(value, kind):
            raise UsageError(f"{path}: {where}{key}: expected {'a list' if kind is list else 'an object'}, "
                             f"got {type(value).__name__ if value is not None else 'nothing'}")
        return value

    cam = need(need(result, "camera", ""), "map", "camera.")
    need(result, "provenance", "")
    objects = need(result, "objects", "", list)
    if not objects:
        raise UsageError(f"{path}: objects: expected at least one object, got []")
    for k in CAMERA_NAMES:
        if not isinstance(cam.get(k), (int, float)):
            raise UsageError(f"{path}: camera.map.{k}: expected a number, got {cam.get(k)!r}")
    for i, o in enumerate(objects):
        mp = need(o, "map", f"objects[{i}].")
        for k in OBJECT_NAMES:
            if not isinstance(mp.get(k), (int, float)):
                raise UsageError(f"{path}: objects[{i}].map.{k}: expected a number, got {mp.get(k)!r}")


def _run(args) -> int:
    import matplotlib
    import numpy as np

    matplotlib.use("Agg")
    from ..io.result import read_result, result_from_v1
    from ..pipeline import rebuild_model, result_draws
    from ..vision import plotting
    from ..vision.images import ImageWarning

    path = Path(args.result)
    if path.is_dir() or path.name == "batch.json":
        return _dataset(path / "batch.json" if path.is_dir() else path, args)
    with usage_errors():  # wrong format key, or not JSON
        d = read_result(path)
    scene = find_scene(d, path, args.scene)
    chains = None
    if d["format"] == "creference-result/1":
        kept = (d.get("posterior") or {}).get("draws") or {}
        chains = np.asarray(kept["chain"]) if "chain" in kept else None
        d = result_from_v1(d, scene)
    check_result(d, path)
    ids = [o["id"] for o in d["objects"]]
    unknown = [i for i in args.object or [] if i not in ids]
    if unknown:
        raise UsageError(f"--object {unknown[0]}: no such object (objects: {ids[:10]}{'…' if len(ids) > 10 else ''})")
    try:
        model = rebuild_model(d, scene)
        cams, objs, source = result_draws(d, model, n=2000, seed=0)
    except (KeyError, TypeError, ValueError) as exc:
        raise UsageError(f"{path}: the model cannot be rebuilt from the result ({' '.join(str(exc).split())})") from None
    if source == "laplace" and not args.quiet:
        print("note: the result keeps no posterior draws: the spread shown is the Laplace approximation at the MAP, "
              "and there is no rank plot")
    chains = plotting.kept_chains(d) if chains is None else chains
    if source == "posterior" and chains is None and not args.quiet:
        print("note: the result does not say which chain each of its draws came from: no rank plot")
    chosen = [ids.index(i) for i in args.object] if args.object else [0]
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", ImageWarning)
        figures = plotting.scene_figures(scene, d, (cams, objs) if len(cams) else None, source=source,
                                         chains=chains, chosen=chosen)
    for w in caught:  # a photo that cannot be read: one line; other warnings as they were
        if not issubclass(w.category, ImageWarning):
            warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
    for message in dict.fromkeys(str(w.message) for w in caught if issubclass(w.category, ImageWarning)):
        print(f"warning: {message}", file=sys.stderr)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    for name, fig in figures.items():
        _save(fig, out / f"{name}.{args.format}", args)
    return 0


def _save(fig, target: Path, args) -> None:
    from ..io.files import atomic_path

    with atomic_path(target) as tmp:
        fig.savefig(tmp, dpi=args.dpi, format=args.format)
    if not args.quiet:
        print(f"wrote {target}")


def _dataset(path: Path, args) -> int:
    """The data set's figure of a batch (:func:`~creference_bayes.vision.dataset_figures.dataset_figure`)."""
    import matplotlib

    matplotlib.use("Agg")
    from ..io.validation import read_json
    from ..vision.dataset_figures import dataset_figure
    from ..workflows.batch import BATCH_FORMAT

    if not path.is_file():
        raise UsageError(f"{path}: no such file (a batch's folder holds batch.json)")
    with usage_errors(f"{path}: "):
        d = read_json(path)
    if not isinstance(d, dict) or d.get("format") != BATCH_FORMAT:
        got = d.get("format") if isinstance(d, dict) else type(d).__name__
        raise UsageError(f"{path}: format: expected {BATCH_FORMAT!r}, got {got!r}")
    if not d.get("dataset"):
        raise UsageError(f"{path}: the batch learnt nothing from its frames (no dataset block): frames that share a "
                         "camera id, frames with references, or enough frames of one setting teach each other "
                         "(docs/batch.md)")
    with usage_errors(f"{path}: "):
        fig = dataset_figure(d["dataset"])
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    _save(fig, out / f"dataset.{args.format}", args)
    return 0

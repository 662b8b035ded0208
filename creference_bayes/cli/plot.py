"""``creference plot RESULT.json [--scene SCENE] [--out DIR]``: the figures of an estimate.

Writes ``top_view.png``, ``pairs.png`` and ``ranks.png`` (these need the posterior) and
``boxes.png`` (this needs the scene). Posterior draws come from the NetCDF file named in the
result (``--netcdf`` at estimation) when it exists, else from the draws kept in the JSON.
The scene is ``--scene``, else the result's ``scene`` name looked up next to the result file, in
the current directory, then among the package's shipped scenes. Either way it must be the scene
the result was estimated from: its target id, image size and content hash must match the result's
``scene_id`` (else a one-line error, exit 2). Results written before ``scene_id`` existed are
checked on their target id only, with a warning that the scene could not be checked fully.

A frame's result (``creference-result/2``) gets ``frame_boxes``, ``frame_top_view`` and
``frame_camera`` instead (:mod:`.frame_plot`, docs/frames.md).
"""

from __future__ import annotations

from importlib import resources
from pathlib import Path
from ..io.files import read_text

__all__ = ["register"]


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "plot", help="plot a result: projected boxes, pair plot, ranks, top view",
        description="Draw the figures of a result: boxes.png (the MAP and posterior boxes over the "
                    "photo or a blank canvas; needs the scene), top_view.png (the ground seen from "
                    "above), pairs.png and ranks.png (need the posterior). See docs/user_guide.md.")
    p.add_argument("result", metavar="RESULT.json",
                   help="a creference-result/1 file written by `creference estimate --out`, or a frame's "
                        "creference-result/2 (then frame_boxes, frame_top_view and frame_camera, and frame_zooms when "
                        "many objects need a zoom panel; docs/frames.md)")
    p.add_argument("--scene", metavar="SCENE.json",
                   help="the scene the result was estimated from (default: the result's scene "
                        "name, looked up next to the result, in the current directory, then among "
                        "the shipped scenes); a different scene is refused")
    p.add_argument("--out", metavar="DIR", default=".", help="output directory (default: .)")
    p.add_argument("--format", default="png", choices=["png", "pdf", "svg"],
                   help="file format of the figures (default: %(default)s)")
    p.add_argument("--dpi", type=int, default=110, help="resolution of PNG files (default: %(default)s)")
    p.add_argument("--quiet", action="store_true", help="print nothing but errors")
    p.set_defaults(func=_run)


def _find_scene(result: dict, result_path: Path, explicit: str | None):
    from .main import UsageError
    from ..io.result import scene_candidates
    from ..io.scene import load_scene

    if explicit:
        return _checked(result, load_scene(explicit), "--scene " + str(explicit))
    name = result.get("scene")
    if not name and not result.get("batch"):
        return None
    candidates = scene_candidates(result, result_path)
    for c in candidates:
        if c.is_file():
            return _checked(result, load_scene(c), f"scene {str(c)!r} (found by the result's "
                                                   "scene name; pass --scene)")
    raise UsageError(f"scene: {name!r} not found next to the result, in the current directory or "
                     "among the shipped scenes; pass --scene")


def scene_mismatch(result: dict, scene) -> str | None:
    """What differs between the scene a result records (``scene_id``) and ``scene``; None if
    nothing does. A result without ``scene_id`` (written before it existed) is compared on its
    ``target`` id only."""
    from ..io.scene import scene_fingerprint

    recorded = result.get("scene_id")
    if not isinstance(recorded, dict):
        recorded = {"target": result.get("target")}
    actual = {"target": scene.target.id, "image_size": [scene.image_width, scene.image_height]}
    diffs = []
    if "target" in recorded and recorded["target"] != actual["target"]:
        diffs.append(f"target {actual['target']!r}, the result's is {recorded['target']!r}")
    if "image_size" in recorded and list(recorded["image_size"]) != actual["image_size"]:
        w, h = actual["image_size"]
        rw, rh = recorded["image_size"]
        diffs.append(f"image {w}x{h} px, the result's is {rw}x{rh}")
    if not diffs and "sha256" in recorded and recorded["sha256"] != scene_fingerprint(scene):
        diffs.append(f"same target and image size but different content: sha256 "
                     f"{scene_fingerprint(scene)[:12]}…, the result's is {str(recorded['sha256'])[:12]}…; "
                     "edited since the estimate?")
    return "; ".join(diffs) or None


def _checked(result: dict, scene, where: str):
    import sys

    from .main import UsageError

    why = scene_mismatch(result, scene)
    if why:
        raise UsageError(f"{where}: not the scene this result was estimated from ({why})")
    if not isinstance(result.get("scene_id"), dict):
        print("warning: the result records no scene_id (written by an older version): only its target "
              "id was checked against the scene", file=sys.stderr)
    return scene


def _run(args) -> int:
    import matplotlib

    matplotlib.use("Agg")
    from ..vision import plotting
    from .main import UsageError
    from ..io.result import load_result_dict

    path = Path(args.result)
    frame_result = _frame_result(path)
    if frame_result is not None:
        from .frame_plot import run_frame_plot

        return run_frame_plot(args, frame_result, path)
    try:
        result = load_result_dict(path)
    except ValueError as exc:  # wrong format key, or not JSON
        raise UsageError(f"{path}: {exc}") from None
    scene = _find_scene(result, path, args.scene)
    idata = _load_netcdf(result, path)
    draws = plotting.draws_from_result(result, idata)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    truth = plotting._truth(scene) if scene is not None else None
    figures = {}
    if scene is not None:
        figures["boxes"] = plotting.plot_boxes(result, scene, draws)
    figures["top_view"] = plotting.plot_top_view(result, draws, scene=scene, truth=truth)
    if draws is not None:
        figures["pairs"] = plotting.plot_pairs(draws, result=result, truth=truth)
        figures["ranks"] = plotting.plot_ranks(draws, result=result)
    elif not args.quiet:
        print("note: the result has no posterior (estimated with --no-posterior): "
              "no pair or rank plot")
    for name, fig in figures.items():
        target = out / f"{name}.{args.format}"
        fig.savefig(target, dpi=args.dpi)
        if not args.quiet:
            print(f"wrote {target}")
    return 0


def _frame_result(path: Path) -> dict | None:
    """The document of a ``creference-result/2`` file (a frame), or None for anything else."""
    import json

    try:
        d = json.loads(read_text(path))
    except (OSError, ValueError):
        return None
    return d if isinstance(d, dict) and d.get("format") == "creference-result/2" else None


def _load_netcdf(result: dict, result_path: Path):
    name = result.get("netcdf")
    if not name:
        return None
    for p in (Path(name), result_path.parent / Path(name).name):
        if p.is_file():
            from ..inference.summary import az

            return az.from_netcdf(p)
    return None

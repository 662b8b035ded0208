"""``creference plot`` and ``creference advise`` on a frame result (``creference-result/2``): its
scene found and checked, the model rebuilt, the figures drawn (docs/frames.md)."""

from __future__ import annotations

from pathlib import Path

from .main import UsageError
from ..io.files import read_text

__all__ = ["check_frame_result", "find_frame_scene", "run_frame_plot", "run_frame_advise"]


def check_frame_result(result: dict, path: Path) -> None:
    """A one-line error naming the first key a frame result lacks (``objects[0].map.x``, …)."""
    from ..models.frame import CAMERA_NAMES, OBJECT_NAMES

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


def find_frame_scene(result: dict, result_path: Path, explicit: str | None):
    """The frame a result was estimated from: ``explicit`` (``--scene``), else the result's
    ``scene`` name next to the result, then in the current directory. Its target ids and image
    size must be the result's (else a one-line error)."""
    from ..io.frame_scene import load_frame
    from ..io.result import scene_candidates

    if explicit:
        return _checked(result, load_frame(explicit), f"--scene {explicit}")
    name = result.get("scene")
    if not name and not result.get("batch"):
        raise UsageError(f"{result_path}: the result names no scene; pass --scene")
    for c in scene_candidates(result, result_path):
        if c.is_file():
            return _checked(result, load_frame(c), f"scene {str(c)!r} (found by the result's scene name; pass --scene)")
    raise UsageError(f"scene: {name!r} not found next to the result or in the current directory; pass --scene")


def _checked(result: dict, frame, where: str):
    ids = [o["id"] for o in result["objects"]]
    mine = [t.id for t in frame.targets]
    diffs = []
    if ids != mine:
        diffs.append(f"targets {mine[:5]}{'…' if len(mine) > 5 else ''}, the result's are {ids[:5]}{'…' if len(ids) > 5 else ''}")
    size = result.get("image_size")
    if size is not None and list(size) != [frame.image_width, frame.image_height]:
        diffs.append(f"image {frame.image_width}x{frame.image_height} px, the result's is {size[0]}x{size[1]}")
    if diffs:
        raise UsageError(f"{where}: not the frame this result was estimated from ({'; '.join(diffs)})")
    return frame


def run_frame_plot(args, result: dict, path: Path) -> int:
    """Write ``frame_boxes``, ``frame_top_view`` and ``frame_camera`` figures of a frame result, and
    ``frame_zooms`` when more objects need a zoom panel than fit beside the top view."""
    import numpy as np

    from ..frame_pipeline import frame_draws, map_state, rebuild_model
    from ..vision import frame_figures as ff

    check_frame_result(result, path)
    frame = find_frame_scene(result, path, args.scene)
    try:
        model = rebuild_model(result, frame)
    except (KeyError, ValueError) as exc:
        raise UsageError(f"{path}: the model cannot be rebuilt from the result ({exc})") from None
    camera, objects = map_state(result)
    cams, objs, source = frame_draws(result, model, n=2000, seed=0)
    label = "posterior draws" if source == "posterior" else "draws of the Laplace approximation"
    if source == "laplace" and not args.quiet:
        print("note: the result keeps no posterior draws: the spread shown is the Laplace approximation "
              "at the MAP (docs/frames.md)")
    draws = (cams, objs) if len(cams) else None
    prob = ((result["camera"].get("posterior") or {}).get("hdi") or {}).get("prob", 0.9)
    figures = {"frame_boxes": ff.plot_frame_boxes(frame, camera, objects, draws, draws_label=label),
               "frame_top_view": ff.plot_frame_top_view(frame, camera, objects, draws, prob=prob, draws_label=label)}
    zoom = ff.zoom_indices(frame, objects, draws)
    if len(zoom) > ff.MAX_ZOOM_PANELS:  # too many to sit beside the top view: a figure of their own
        figures["frame_zooms"] = ff.plot_frame_zooms(frame, camera, objects, draws, indices=zoom, prob=prob,
                                                     draws_label=label)
    if draws is not None:
        figures["frame_camera"] = ff.plot_frame_camera(cams, model.complete_camera(camera[None])[0],
                                                       np.asarray(model.camera_free), truth=frame.ground_truth,
                                                       draws_label=label)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    for name, fig in figures.items():
        target = out / f"{name}.{args.format}"
        tmp = target.with_name(f".{target.name}.tmp")
        fig.savefig(tmp, dpi=args.dpi, format=args.format)
        tmp.replace(target)
        if not args.quiet:
            print(f"wrote {target}")
    return 0


def run_frame_advise(args, settings) -> int:
    """``creference advise FRAME.json|RESULT.json`` on a frame: the table, ``--out`` JSON."""
    import json

    import numpy as np

    from ..frame_pipeline import build_frame_model, map_state, rebuild_model
    from ..inference.frame_map import optimize_frame
    from ..io.files import atomic_write_json
    from ..io.frame_scene import load_frame
    from ..workflows.advice.frame import advise_frame, frame_advice_table
    from .main import check_output_file

    check_output_file("--out", args.out)
    path = Path(args.input)
    d = json.loads(read_text(path))
    try:
        if d.get("format") == "creference-result/2":
            check_frame_result(d, path)
            frame = find_frame_scene(d, path, args.scene)
            model = rebuild_model(d, frame)
            camera, objects = map_state(d)
            hdis = [((o.get("posterior") or {}).get("hdi") or {}).get("distance_m") for o in d["objects"]]
            width = None if any(h is None for h in hdis) else np.array([b - a for a, b in hdis], float)
            prob = ((d["camera"].get("posterior") or {}).get("hdi") or {}).get("prob")
            if width is not None and prob is not None and abs(prob - settings.hdi_prob) > 1e-9:
                width = None  # another probability: the Laplace approximation's at ours
            temperature = float(d["provenance"].get("temperature", 1.0))
        else:
            if args.scene is not None:
                raise UsageError("--scene: only for a result file (INPUT is a scene)")
            frame = load_frame(path)
            model, _ = build_frame_model(frame)
            est = optimize_frame(model)
            camera, objects, width, temperature = est.camera, est.objects, None, 1.0
        advice = advise_frame(model, frame, camera, objects, width_now=width, settings=settings,
                              temperature=temperature)
    except (KeyError, TypeError) as exc:
        raise UsageError(f"{path}: the frame's model cannot be rebuilt from it ({exc!r})") from None
    except ValueError as exc:
        raise UsageError(" ".join(str(exc).split())) from None
    if args.out is not None:
        atomic_write_json(args.out, advice.to_dict())
    if not args.quiet:
        print(frame_advice_table(advice))
        if args.out is not None:
            print(f"wrote {args.out}")
    return 0

"""``creference plot RESULT.json [--scene SCENE] [--out DIR]``: the figures of an estimate.

Writes ``top_view.png``, ``pairs.png`` and ``ranks.png`` (these need the posterior) and
``boxes.png`` (this needs the scene). Posterior draws come from the NetCDF file named in the
result (``--netcdf`` at estimation) when it exists, else from the draws kept in the JSON.
The scene is ``--scene``, else the result's ``scene`` name looked up next to the result file, in
the current directory, then among the package's shipped scenes.
"""

from __future__ import annotations

from importlib import resources
from pathlib import Path

__all__ = ["register"]


def register(subparsers) -> None:
    p = subparsers.add_parser("plot", help="plot a result: projected boxes, pair plot, ranks, top view")
    p.add_argument("result", metavar="RESULT.json")
    p.add_argument("--scene", metavar="SCENE.json", help="the scene the result came from")
    p.add_argument("--out", metavar="DIR", default=".", help="output directory (default: .)")
    p.add_argument("--format", default="png", choices=["png", "pdf", "svg"])
    p.add_argument("--dpi", type=int, default=110, help="resolution of PNG files (default: %(default)s)")
    p.add_argument("--quiet", action="store_true", help="print nothing but errors")
    p.set_defaults(func=_run)


def _find_scene(result: dict, result_path: Path, explicit: str | None):
    from .main import UsageError
    from ..io.scene import load_scene

    if explicit:
        return load_scene(explicit)
    name = result.get("scene")
    if not name:
        return None
    candidates = [result_path.parent / name, Path.cwd() / name,
                  Path(str(resources.files("creference_bayes") / "data" / name))]
    for c in candidates:
        if c.is_file():
            return load_scene(c)
    raise UsageError(f"scene: {name!r} not found next to the result, in the current directory or "
                     "among the shipped scenes; pass --scene")


def _run(args) -> int:
    import matplotlib

    matplotlib.use("Agg")
    from ..vision import plotting
    from .main import UsageError
    from ..io.result import load_result_dict

    path = Path(args.result)
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


def _load_netcdf(result: dict, result_path: Path):
    name = result.get("netcdf")
    if not name:
        return None
    for p in (Path(name), result_path.parent / Path(name).name):
        if p.is_file():
            from ..inference.summary import az

            return az.from_netcdf(p)
    return None

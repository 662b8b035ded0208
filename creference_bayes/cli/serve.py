"""``creference serve``: the Label Studio ML backend (docs/serve.md)."""

from __future__ import annotations

import ipaddress
import logging
import os
import sys
from pathlib import Path

from .main import UsageError, advanced_group, require, seed_value, usage_errors

__all__ = ["register", "TOKEN_ENV"]

#: The environment variable holding the service's token (a token on the command line would show
#: in the process list).
TOKEN_ENV = "CREFERENCE_SERVE_TOKEN"


def _token(args) -> str | None:
    if args.token_file is not None:
        try:
            token = Path(args.token_file).read_text("utf-8").strip()
        except OSError as exc:
            raise UsageError(f"--token-file: {args.token_file}: {exc.strerror or exc}") from None
        require(bool(token), "--token-file", "a file holding the token", args.token_file)
        return token
    return os.environ.get(TOKEN_ENV, "").strip() or None


def _loopback(host: str) -> bool:
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def _run_serve(args) -> int:
    from ..serve.predictions import serve_config

    if args.print_config:
        sys.stdout.write(serve_config(args.lines))
        return 0
    require(0 < args.iou_threshold < 1, "--iou-threshold", "a number in (0, 1)", args.iou_threshold)
    require(args.max_body_mb > 0, "--max-body-mb", "a size > 0 (MiB)", args.max_body_mb)
    require(args.time_budget >= 0, "--time-budget", "seconds >= 0", args.time_budget)
    require(1 <= args.port <= 65535, "--port", "a port number in [1, 65535]", args.port)
    token = _token(args)
    if not _loopback(args.host) and token is None:
        raise UsageError(f"--host {args.host}: the service answers other machines only with a token "
                         f"(--token-file FILE or {TOKEN_ENV})")
    if args.image_root is not None and not Path(args.image_root).is_dir():
        raise UsageError(f"--image-root: {args.image_root} is not a folder")
    try:
        from werkzeug.serving import make_server

        from ..serve.app import ServeSettings, create_app
        from ..workflows.advice import AdviceSettings
    except ImportError as exc:
        raise UsageError(str(exc) if "creference" in str(exc) else
                         'creference serve needs Flask: pip install "creference-bayes[serve]"') from None
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s %(levelname)s %(message)s")
    with usage_errors("--advice-draws/--advice-futures: "):
        advice = AdviceSettings(n_draws=args.advice_draws, n_futures=args.advice_futures)
    settings = ServeSettings(state_dir=Path(args.state), image_root=None if args.image_root is None else
                             Path(args.image_root), token=token, max_body_bytes=int(args.max_body_mb * 2**20),
                             iou_threshold=args.iou_threshold, seed=args.seed, background=not args.no_background,
                             time_budget_s=args.time_budget,
                             advice_settings=advice)
    try:
        app = create_app(settings)
    except ValueError as exc:  # a batch.json in --state that is not a batch's
        raise UsageError(f"--state: {exc}") from None
    try:
        server = make_server(args.host, args.port, app, threaded=True)
    except OSError as exc:
        raise UsageError(f"cannot listen on {args.host}:{args.port}: {exc.strerror or exc}") from None
    print(f"creference serve: listening on http://{args.host}:{args.port} (folder {args.state}; "
          f"{'token required' if token else 'no token'}); stop with Ctrl+C", file=sys.stderr, flush=True)
    priors = app.extensions["creference"]["worker"].priors
    if priors is not None:
        print(f"creference serve: each frame takes the priors of {priors.describe()}", file=sys.stderr, flush=True)
    try:
        server.serve_forever()
    finally:
        server.server_close()
    return 0


def register(subparsers) -> None:
    """Add ``serve`` to the ``creference`` command."""
    p = subparsers.add_parser(
        "serve", help="a Label Studio ML backend: each frame's estimate drawn in the annotation tool",
        description="Answer Label Studio's ML backend protocol (/health, /setup, /predict, /webhook): predictions "
                    "with each target's projected box, its distance and label quality, the frame's next request; "
                    "new annotations are re-estimated in the background (docs/serve.md). Needs the [serve] extra.")
    p.add_argument("--state", default="creference-serve", metavar="DIR",
                   help="the service's folder: tasks, results, advice; a batch folder (creference batch --out DIR): "
                        "each frame takes the priors its data set learnt (default: %(default)s)")
    p.add_argument("--image-root", default=None, metavar="DIR",
                   help="the folder of the photos (horizon, EXIF); a task naming a file outside it is refused "
                        "(default: no photo is read)")
    p.add_argument("--host", default="127.0.0.1", help="address to listen on (default: %(default)s, this machine only)")
    p.add_argument("--port", type=int, default=9090, help="port (default: %(default)s)")
    p.add_argument("--token-file", default=None, metavar="FILE",
                   help=f"a file holding the token requests must carry (default: ${TOKEN_ENV}; none: no check)")
    p.add_argument("--print-config", action="store_true",
                   help="print the labelling config with the estimate's controls and exit")
    p.add_argument("--lines", default="keypoints", choices=("keypoints", "vectors"),
                   help="how the printed config draws lines (default: %(default)s)")
    p.add_argument("--iou-threshold", type=float, default=0.7, metavar="T",
                   help="label quality is P(IoU >= T) (default: %(default)s)")
    adv = advanced_group(p)
    adv.add_argument("--max-body-mb", type=float, default=16.0, metavar="MB",
                     help="larger requests are refused with 413 (default: %(default)s MiB)")
    adv.add_argument("--time-budget", type=float, default=60.0, metavar="S",
                     help="a /predict estimates no more frames after S seconds and queues the rest for the background "
                          "(Label Studio waits 100 s; default: %(default)s)")
    adv.add_argument("--seed", type=seed_value, default=0, help="base seed (default: %(default)s)")
    adv.add_argument("--no-background", action="store_true",
                     help="do not sample a posterior for frames /predict estimates (only webhooks queue jobs)")
    adv.add_argument("--advice-draws", type=int, default=200, metavar="N",
                     help="posterior draws the next request is weighed on (default: %(default)s)")
    adv.add_argument("--advice-futures", type=int, default=40, metavar="N",
                     help="simulated outcomes per candidate request (default: %(default)s)")
    p.set_defaults(func=_run_serve)

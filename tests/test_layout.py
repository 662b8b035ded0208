"""The package's architecture: folders by concern, imports only downwards, a pure numerical core."""

import ast
import os
import subprocess
import sys
from pathlib import Path

import pytest

PKG = Path(__file__).resolve().parents[1] / "creference_bayes"

#: Each folder (or top-level module) may import only from its own rank or below.
LAYERS = {"core": 0, "models": 1, "io": 2, "inference": 3, "vision": 4, "camera_setup": 5,
          "pipeline": 5, "bench": 6, "evaluation": 6, "workflows": 7, "serve": 7, "cli": 8}
HEAVY = ("cv2", "emcee", "arviz", "matplotlib", "dask", "poselib", "shapely", "PIL", "tqdm")
STDLIB = set(sys.stdlib_module_names)


def _modules():
    for path in sorted(PKG.rglob("*.py")):
        rel = path.relative_to(PKG)
        if rel.parts[0] in ("__init__.py", "__main__.py"):
            continue  # the public API and the entry point re-export from everywhere
        yield path, rel


def _layer(rel: Path) -> str:
    return rel.parts[0] if len(rel.parts) > 1 else rel.stem


def _imports(path: Path, rel: Path):
    """(absolute module name, line) of every import in ``path``, relative ones resolved."""
    package = ["creference_bayes", *rel.parts[:-1]]
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            for a in node.names:
                yield a.name, node.lineno
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package[:len(package) - node.level + 1]
                mod = ".".join(base + ([node.module] if node.module else []))
                if node.module is None:  # from .. import x: x may be a module
                    for a in node.names:
                        yield f"{mod}.{a.name}", node.lineno
                    continue
                yield mod, node.lineno
            else:
                yield node.module, node.lineno


def test_every_module_is_in_a_known_folder():
    unknown = {_layer(rel) for _, rel in _modules()} - set(LAYERS)
    assert not unknown, f"modules outside the layout: {sorted(unknown)}"


def test_no_module_or_public_name_is_named_for_one_kind_of_scene():
    """One unit, one path: a scene of one object and a scene of sixty go through the same modules,
    so nothing is written twice under a ``frame_`` (or ``target_``) name."""
    twins = [str(rel) for _, rel in _modules() if rel.stem.startswith(("frame", "target_", "single_"))]
    names = []
    for path, rel in _modules():
        if rel.parts[0] == "evaluation":
            continue  # KITTI's own word for one of its images
        for node in ast.parse(path.read_text()).body:
            if isinstance(node, (ast.FunctionDef, ast.ClassDef)) and not node.name.startswith("_") \
                    and (node.name.startswith("frame_") or node.name.endswith("_frame")):
                names.append(f"{rel}: {node.name}")
    assert not twins, f"modules named for a kind of scene: {twins}"
    assert not names, "public names for a kind of scene:\n" + "\n".join(names)


def test_no_module_imports_a_folder_above_it():
    violations = []
    for path, rel in _modules():
        here = LAYERS[_layer(rel)]
        for mod, line in _imports(path, rel):
            parts = mod.split(".")
            if parts[0] != "creference_bayes" or len(parts) < 2 or parts[1] not in LAYERS:
                continue
            if LAYERS[parts[1]] > here:
                violations.append(f"{rel}:{line} imports {mod}")
    assert not violations, "imports running upwards:\n" + "\n".join(violations)


@pytest.mark.parametrize("folder", ["core", "models"])
def test_core_and_models_import_numpy_scipy_and_the_standard_library_only(folder):
    allowed = STDLIB | {"numpy", "scipy", "creference_bayes"}
    bad = []
    for path, rel in _modules():
        if rel.parts[0] != folder:
            continue
        for mod, line in _imports(path, rel):
            top = mod.split(".")[0]
            if top not in allowed:
                bad.append(f"{rel}:{line} imports {mod}")
            elif top == "creference_bayes" and mod.split(".")[1] not in ("core", "models"):
                bad.append(f"{rel}:{line} imports {mod}")
    assert not bad, "\n".join(bad)


#: Each heavy library's one adapter: the only module that imports it (matplotlib is the figure
#: modules' own, vision/ and the bench's and the plot command's figures).
ADAPTERS = {"emcee": "inference/emcee_moves.py", "arviz": "inference/summary.py", "pandas": "inference/summary.py",
            "tqdm": "inference/progress.py", "threadpoolctl": "inference/threads.py", "cv2": "vision/horizon.py",
            "PIL": "vision/images.py", "shapely": "evaluation/iou3d.py", "poselib": "bench/peers.py",
            "dask": "workflows/batch/engines.py", "distributed": "workflows/batch/engines.py"}


def test_each_heavy_library_is_imported_by_its_one_adapter():
    found = {}
    for path, rel in _modules():
        for mod, line in _imports(path, rel):
            if mod.split(".")[0] in ADAPTERS:
                found.setdefault(mod.split(".")[0], set()).add(rel.as_posix())
    bad = [f"{lib} imported by {sorted(where)}, expected {ADAPTERS[lib]} alone" for lib, where in sorted(found.items())
           if where != {ADAPTERS[lib]}]
    assert not bad, "\n".join(bad)
    assert {"emcee", "arviz", "tqdm", "cv2"} <= set(found)  # the scan sees the adapters themselves


def test_importing_core_and_models_loads_no_heavy_library():
    code = ("import sys, pkgutil, importlib, creference_bayes.core as c, creference_bayes.models as m\n"
            "for pkg in (c, m):\n"
            "    for info in pkgutil.iter_modules(pkg.__path__):\n"
            "        importlib.import_module(f'{pkg.__name__}.{info.name}')\n"
            f"print(','.join(x for x in {HEAVY!r} if x in sys.modules))\n")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip() == "", f"loaded by importing core and models: {proc.stdout.strip()}"


def test_the_advice_and_the_block_kernel_load_no_heavy_library():
    """The advice moves weak futures by the sampler's block kernel without the sampler's driver:
    neither imports emcee (with scipy.stats, most of an advice process's start-up) or a plotting or
    image library."""
    code = ("import sys, creference_bayes.workflows.advice, creference_bayes.inference.moves\n"
            f"print(','.join(x for x in {HEAVY + ('scipy.stats',)!r} if x in sys.modules))\n")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip() == "", f"loaded by importing the advice: {proc.stdout.strip()}"


def test_estimates_run_with_one_blas_thread_even_when_numpy_came_first():
    """A user script that imports NumPy before the package gets the default (threaded) BLAS; the
    estimate limits it to one thread while it runs, unless the user chose a count."""
    code = ("import os\n"
            "for v in ('OPENBLAS_NUM_THREADS', 'OMP_NUM_THREADS', 'MKL_NUM_THREADS'): os.environ.pop(v, None)\n"
            "import numpy\n"
            "from threadpoolctl import threadpool_info\n"
            "import creference_bayes\n"
            "from creference_bayes.inference.threads import single_threaded_blas\n"
            "with single_threaded_blas():\n"
            "    inside = [i['num_threads'] for i in threadpool_info() if i['user_api'] == 'blas']\n"
            "print(max(inside), creference_bayes.inference.threads.USER_SET_THREADS)\n")
    env = {k: v for k, v in os.environ.items() if k not in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")}
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, env=env)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.split() == ["1", "False"]

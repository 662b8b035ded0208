"""From a batch folder to KITTI labels with their uncertainty (docs/labels.md).

Per image (``NAME`` = the image's file name without extension, or the scene file's when the
scene has no image; the scenes of one image share its files, :mod:`.kitti`)::

    OUT/label_2/NAME.txt        one KITTI line per target: the MAP box, score = P(IoU ≥ 0.7)
    OUT/calib/NAME.txt          its P2 (the scene's KITTI P2, else K·[R | 0] in the gravity-aligned frame)
    OUT/uncertainty/NAME.json   the camera and, per target, MAP, posterior, quality, box draws

The boxes are read from ``results/KEY.json`` (``creference-result/2``; a ``creference-result/1``
result is converted, :func:`~creference_bayes.io.result.result_from_v1`) and the
scenes from the copies ``scenes/KEY.json`` that ``creference batch`` keeps; a copy whose
canonical content is not the scene the result records (``scene_id.sha256``) is not used (the
scene changed: rerun the batch).
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field
from pathlib import Path, PurePath

from ...io.result import RESULT_FORMAT, batch_fields, canonical_sha256, read_result, result_from_v1
from ...io.scene import SceneError, SceneWarning, load_scene
from ...io.validation import read_json
from ..batch.files import result_paths
from .kitti import LabelInput, ObjectLabel, write_labels
from .quality import IOU_THRESHOLDS

__all__ = ["LabelInput", "ObjectLabel", "LabelExport", "load_batch", "export_labels"]


def _image_group(key: str, result: dict, copy: dict) -> tuple[str, str]:
    """(the image a scene is of, its label name): the image's path (relative to the original scene
    file), else the scene itself."""
    source = PurePath(result["batch"]["source"])
    image = (copy.get("image") or {}).get("path")
    if image is None:
        return f"scene:{key}", source.stem
    path = PurePath(image) if PurePath(image).is_absolute() else source.parent / image
    return f"image:{Path(path).resolve(strict=False)}", PurePath(image).stem


def load_batch(batch_dir: str | Path) -> tuple[list[LabelInput], list[dict]]:
    """The batch's results that can be labelled (a :class:`~.kitti.LabelInput` per scene, its
    result as ``creference-result/2``) and the others with the reason (``key``, ``reason``).

    Raises
    ------
    FileNotFoundError : ``batch_dir`` has no ``results/``
    """
    batch_dir = Path(batch_dir)
    inputs, skipped = [], []
    for key, path in result_paths(batch_dir, check=True).items():
        try:
            result = read_result(path)
            if "batch" not in result:
                raise ValueError("not a result of creference batch")
            copy_path = batch_dir / batch_fields(result, path)["scene_copy"]  # inside batch_dir
            copy = read_json(copy_path)
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", SceneWarning)
                scene = load_scene(copy_path)
            if canonical_sha256(copy) != (result.get("scene_id") or {}).get("sha256"):
                skipped.append({"key": key, "reason": "its scene copy is not the scene of the result "
                                                      "(rerun creference batch)"})
                continue
            if result["format"] != RESULT_FORMAT:
                result = result_from_v1(result, scene)
        except (OSError, ValueError, KeyError, TypeError, SceneError) as exc:
            skipped.append({"key": key, "reason": f"cannot be read: {' '.join(str(exc).split())}"})
            continue
        if not result.get("draws"):
            skipped.append({"key": key, "reason": "no posterior draws (batch run with --no-posterior?)"})
            continue
        group, name = _image_group(key, result, copy)
        inputs.append(LabelInput(key, result, scene, name=name, group=group))
    return inputs, skipped


@dataclass(frozen=True)
class LabelExport:
    """What :func:`export_labels` wrote: the objects, the images' names, the skipped results, the
    scenes that failed in the batch and, per labelled scene's key, the fingerprint of the scene its
    result is of (``scene_id.sha256``)."""

    objects: list[ObjectLabel]
    images: list[str]
    skipped: list[dict]
    failed_scenes: list[dict]
    fingerprints: dict = field(default_factory=dict)
    removed: list[str] = field(default_factory=list)  # stale files of a previous run, removed
    kept: list[str] = field(default_factory=list)  # stale files of a previous run changed since: kept


#: The list of the label files ``labels`` wrote in its folder (path → sha256), so that a later run
#: removes those of images no longer in the batch and nothing else.
MANIFEST = ".creference-labels.json"
MANIFEST_FORMAT = "creference-labels-manifest/1"
_LABEL_FOLDERS = ("label_2", "calib", "uncertainty")


def _sha256(path: Path) -> str:
    import hashlib

    return hashlib.sha256(path.read_bytes()).hexdigest()


def _replace_manifest(out: Path, names: list[str]) -> tuple[list[str], list[str]]:
    """Remove the files the previous run listed in ``out``'s manifest that this run did not write
    (images no longer in the batch), unless changed since (kept); write the new manifest. Returns
    (removed, kept), paths relative to ``out``."""
    from ...io.files import atomic_write_json

    now = {}
    for name in names:
        for rel in (f"label_2/{name}.txt", f"calib/{name}.txt", f"uncertainty/{name}.json"):
            if (out / rel).is_file():
                now[rel] = _sha256(out / rel)
    try:
        before = read_json(out / MANIFEST)
        before = before["files"] if before.get("format") == MANIFEST_FORMAT and isinstance(before["files"], dict) else {}
    except (OSError, ValueError, KeyError, AttributeError, TypeError):
        before = {}
    removed, kept = [], []
    for rel, sha in sorted(before.items()):
        parts = PurePath(rel).parts if isinstance(rel, str) else ()
        if rel in now or len(parts) != 2 or parts[0] not in _LABEL_FOLDERS or not (out / rel).is_file():
            continue  # rewritten now, gone already, or not a label file of ours
        if _sha256(out / rel) == sha:
            (out / rel).unlink()
            removed.append(rel)
        else:
            kept.append(rel)
    atomic_write_json(out / MANIFEST, {"format": MANIFEST_FORMAT, "files": now})
    return removed, kept


def export_labels(batch_dir: str | Path, out: str | Path, *, type_name: str | None = None,
                  score_iou: float = 0.7, n_draws: int = 100) -> LabelExport:
    """Write ``label_2/``, ``calib/`` and ``uncertainty/`` for every labelled image of a batch.

    Parameters
    ----------
    batch_dir : a ``creference batch`` folder
    out : the label folder (created)
    type_name : the KITTI type of every object (default: each target's class, else its id with
        whitespace turned into ``_``)
    score_iou : the IoU threshold t of the score P(IoU ≥ t), one of :data:`IOU_THRESHOLDS`
    n_draws : posterior draws per object in the sidecar

    Raises
    ------
    ValueError : a bad option (named), or two images that would share a label name
    """
    if float(score_iou) not in IOU_THRESHOLDS:
        raise ValueError(f"score_iou: expected one of {list(IOU_THRESHOLDS)}, got {score_iou!r}")
    if type_name is not None and (not type_name or any(c.isspace() for c in type_name)):
        raise ValueError(f"type: a KITTI class name has no whitespace, got {type_name!r}")
    if n_draws < 1:
        raise ValueError(f"draws: expected an integer >= 1, got {n_draws!r}")
    inputs, skipped = load_batch(batch_dir)
    groups: dict[str, list[LabelInput]] = {}
    for inp in inputs:
        groups.setdefault(inp.group, []).append(inp)
    names: dict[str, str] = {}
    for group, members in groups.items():
        name = members[0].name
        if name in names:
            raise ValueError(f"two images would share the label name {name!r}: {names[name]} and "
                             f"{group} (export them from separate batches)")
        names[name] = group
    objects = []
    for name in sorted(names):
        objs, _ = write_labels(out, name, groups[names[name]], type_name=type_name, score_iou=score_iou,
                               n_draws=n_draws)
        objects += objs
    failed = []
    for path in sorted((Path(batch_dir) / "errors").rglob("*.json")):
        if path.name.startswith("."):
            continue
        try:
            d = read_json(path)
            failed.append({"key": d["key"], "error": d["error"]})
        except (OSError, ValueError, KeyError):
            continue
    removed, kept = _replace_manifest(Path(out), sorted(names)) if names else ([], [])
    return LabelExport(objects, sorted(names), skipped, failed,
                       {inp.key: (inp.result.get("scene_id") or {}).get("sha256") for inp in inputs}, removed, kept)

"""A data set's learned priors in the service: when ``creference serve --state DIR`` runs in a
batch folder (``DIR/batch.json``, made by ``creference batch … --out DIR``), each task's frame is
estimated as a frame of that data set would be (docs/serve.md, "A data set's priors").

The data-set layer (:mod:`~creference_bayes.workflows.batch.dataset`) does all of it: its pools are
read from the batch's first pass (:meth:`~creference_bayes.workflows.batch.dataset.DataSet.from_first_pass`,
the quantities the batch learnt), and each frame is handed them by the layer's own
:func:`~creference_bayes.workflows.batch.dataset.hand_back`: its camera's pooled focal length and
mounting (the task's ``camera_id``), the crowd's reference scale, the population of target
distances of its setting (the task's ``setting``, else its camera), the crowd's corner scale and segment floor
(:func:`~creference_bayes.workflows.batch.corner_scales`,
:func:`~creference_bayes.workflows.batch.hand_segments`). A task is no frame of the batch: it
takes the pools of all the batch's frames.

A task whose camera the batch has no pool of (another camera id, or none) is estimated with the
camera priors of a frame alone; its ``dataset`` block says so for each of the camera's quantities
(``"from": "the frame"`` and why), and the crowd's and the setting's pools still apply. The service
estimates with the default settings: what the batch ran with beyond its pools (another model, a
``--distance-range``, options) is not applied.
"""

from __future__ import annotations

import hashlib
import json
import logging
import time
import warnings
from dataclasses import dataclass, replace
from pathlib import Path

from .predictions import Frame

__all__ = ["DataSetPriors"]

log = logging.getLogger("creference.serve")


@dataclass(frozen=True)
class DataSetPriors:
    """The pools of the batch folder the service runs in.

    Attributes
    ----------
    folder : the batch folder
    dataset : the layer's :class:`~creference_bayes.workflows.batch.dataset.DataSet` (the batch's
        frames' readings; every group's pool of all of them)
    scenes : the batch's frames (their annotations make the crowd's corner scale)
    settings : the :class:`~creference_bayes.workflows.batch.BatchSettings` a frame is handed its
        priors under (the defaults: the service's estimate)
    seconds : how long reading the batch took
    """

    folder: Path
    dataset: object
    scenes: tuple
    settings: object
    seconds: float = 0.0

    @classmethod
    def from_folder(cls, folder: str | Path) -> "DataSetPriors | None":
        """The priors of a batch folder, or None when ``folder`` holds no ``batch.json``. The
        pools are the quantities the batch learnt (its ``batch.json`` ``dataset``), read from its
        first pass (``first_pass/``) as ``creference batch`` read them.

        Raises
        ------
        ValueError : a ``batch.json`` that is not a batch's (naming the file)
        """
        from ..io.scene import SceneError, SceneWarning, load_scene
        from ..io.validation import read_json
        from ..workflows.batch import BatchSettings
        from ..workflows.batch.dataset import SHARED, DataSet
        from ..workflows.batch.files import layout
        from ..workflows.batch.rig import camera_id_of

        folder = Path(folder)
        path = folder / "batch.json"
        if not path.is_file():
            return None
        t0 = time.perf_counter()
        doc = read_json(path)
        if not (isinstance(doc, dict) and isinstance(doc.get("scenes"), list)):
            raise ValueError(f"{path}: not a batch folder's batch.json (no 'scenes' list)")
        learnt = doc.get("dataset") or {}
        learn = tuple(name for name, q in SHARED.items() if q.label in learnt)
        first = folder / "first_pass"
        frames, scenes = [], []
        for entry in doc["scenes"]:
            key = entry.get("key") if isinstance(entry, dict) else None
            copies = [layout(f, key)["scene"] for f in (first, folder)] if isinstance(key, str) else []
            copy = next((p for p in copies if p.is_file()), None)
            if copy is None:
                continue
            try:
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore", SceneWarning)
                    scene = load_scene(copy)
            except (SceneError, OSError, ValueError):
                continue
            frames.append((key, camera_id_of(scene)))
            scenes.append(scene)
        # nothing learnt: no first pass to read (the crowd's corner scale is read from the scenes)
        settings = {key: scene.setting for (key, _), scene in zip(frames, scenes) if scene.setting is not None}
        dataset = (DataSet.from_first_pass(frames, first, learn, settings=settings) if learn
                   else DataSet({}, (), dict(frames), settings))
        return cls(folder, dataset, tuple(scenes), BatchSettings(), time.perf_counter() - t0)

    def describe(self) -> str:
        """One line: the frames and what they teach (for the service's start-up message)."""
        summary = self.dataset.summary()
        taught = [f"{label} ({', '.join(entry['groups'])})" for label, entry in summary.items()]
        return (f"the data set of {len(self.scenes)} frame{'s' if len(self.scenes) != 1 else ''} in {self.folder}: "
                f"{'; '.join(taught) if taught else 'no pool (each frame alone but for the corner scale)'}")

    def frame(self, key: str, frame: Frame) -> Frame:
        """Task ``key``'s frame with the priors the data set hands it (module docstring): its
        scene as estimated, the estimate's keyword arguments, its ``dataset`` and ``rig`` blocks,
        and a fingerprint that covers what it was handed."""
        from ..io.scene import scene_fingerprint
        from ..workflows.batch import corner_scales, hand_segments
        from ..workflows.batch.dataset import SHARED, hand_back
        from ..workflows.batch.rig import camera_id_of

        scene = frame.scene
        scale = corner_scales([*self.scenes, scene])[-1] if self.settings.pool_scale else None
        if scale is not None:
            scene = replace(scene, corner_scale=scale)
        camera_id = camera_id_of(scene)
        ds = replace(self.dataset, camera_of={**self.dataset.camera_of, key: camera_id},
                     setting_of={**self.dataset.setting_of, **({key: scene.setting} if scene.setting else {})})
        scene, kwargs, block, rig = hand_back(ds, key, scene, self.settings)
        seg_kwargs, seg_block = hand_segments([*self.scenes, scene], self.settings)[-1]
        kwargs, block = {**seg_kwargs, **kwargs}, {**block, **seg_block}
        for name in ds.learn:  # the camera's quantities the data set could not hand this frame
            if name not in SHARED or SHARED[name].shared_by != "camera":
                continue
            label = SHARED[name].label
            if label not in block:
                why = ("the task names no camera (data.camera_id)" if camera_id is None else
                       f"the data set has no pool of camera {camera_id!r}")
                block[label] = {"from": "the frame", "why": why}
        block = json.loads(json.dumps(block))  # as the stored result will hold it
        fingerprint = scene_fingerprint(scene)
        if block:
            fingerprint = hashlib.sha256(f"{fingerprint}:{json.dumps(block, sort_keys=True)}".encode()).hexdigest()
        return replace(frame, scene=scene, fingerprint=fingerprint, kwargs=kwargs, dataset=block or None, rig=rig)

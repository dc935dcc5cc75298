"""DenseTact optical tactile sensors from Python.

The same code as the project's command-line tools (written in Rust, on Burn), with NumPy arrays
in and out:

- ``Predictor(bundle)``: a trained bundle (``train export``); ``.predict(frame)`` turns a camera
  frame (an HxWx3 uint8 RGB array or a PNG/JPEG path, the full frame or the sensor's crop) into
  depth (mm), the contact mask, the contact patch's point cloud (mm, sensor frame) and, where the
  bundle has the force output, the contact force; bit for bit what ``infer predict`` gives.
- ``Dataset(path, split=None)``: a dataset folder's samples as ``(image, depth, record)``,
  indexable and iterable; ``torch.utils.data.DataLoader(Dataset(...), collate_fn=collate)``.
- ``calibrate(frame)``: a unit's fisheye from its saw-tooth frame (``dataset calibrate``).
- ``label_session(session, sensor, out)``: a capture session into a dataset (``dataset label``).
- ``read_frame(path)``: a camera frame file as the tools read it.
- ``set_spin_ms(ms)``: keep the CPU workers polling that long after each prediction (frames
  at a camera's rate come sooner, for a core kept busy); 0, the default, lets them sleep.

Failures raise ``DenseTactError`` with the tools' messages (the file and the problem).
"""

from __future__ import annotations

import json
import os
from typing import Any, Iterator, List, Optional, Sequence, Tuple, Union

import numpy as np

from ._densetact import (
    CONTACT_THRESHOLD_MM,
    DenseTactError,
    Force,
    Prediction,
    Predictor,
    read_frame,
    set_spin_ms,
)
from . import _densetact

__all__ = [
    "CONTACT_THRESHOLD_MM",
    "Calibration",
    "Dataset",
    "DenseTactError",
    "Force",
    "Prediction",
    "Predictor",
    "calibrate",
    "collate",
    "label_session",
    "read_frame",
    "set_spin_ms",
]

PathLike = Union[str, "os.PathLike[str]"]
Sample = Tuple[Optional[np.ndarray], np.ndarray, dict]


class Dataset:
    """A dataset folder (``dataset generate`` or ``dataset label``), one split or all.

    ``dataset[i]`` is ``(image, depth, record)``: the camera image (HxWx3 uint8 RGB, the crop;
    None for a dataset of depth labels only), the depth label (mm, float32, the crop) and the
    sample's record (its scene, split, statistics and, with force labels, its wrench) as a dict.
    Files are read when a sample is asked for, so a ``DataLoader``'s workers share the work.
    """

    def __init__(self, path: PathLike, split: Optional[str] = None) -> None:
        self._native = _densetact.NativeDataset(os.fspath(path), split)
        self.path: str = os.fspath(path)
        self.split: Optional[str] = split
        #: The dataset's sensor description (its calibrated fisheye and geometry).
        self.sensor: dict = json.loads(self._native.sensor_json())
        #: What ``label_session`` reported, for a dataset it wrote; else empty.
        self.report: List[str] = []

    def __len__(self) -> int:
        return len(self._native)

    # Pickled as its folder and split (reopened on arrival), so that a DataLoader's workers can
    # be spawned processes (macOS, Windows) as well as forked ones.
    def __getstate__(self) -> dict:
        return {"path": self.path, "split": self.split, "report": self.report}

    def __setstate__(self, state: dict) -> None:
        self.__init__(state["path"], state["split"])
        self.report = state["report"]

    def _index(self, i: int) -> int:
        if not isinstance(i, (int, np.integer)):
            raise TypeError(f"dataset indices must be integers, got {type(i).__name__}")
        n = len(self)
        k = int(i) + n if i < 0 else int(i)
        if not 0 <= k < n:
            raise IndexError(f"sample index {i} is out of range: the dataset has {n}")
        return k

    def __getitem__(self, i: int) -> Sample:
        k = self._index(i)
        return self._native.image(k), self._native.depth(k), self.record(k)

    def __iter__(self) -> Iterator[Sample]:
        for k in range(len(self)):
            yield self[k]

    def record(self, i: int) -> dict:
        """Sample ``i``'s record, as a dict."""
        return json.loads(self._native.record_json(self._index(i)))

    def pressure(self, i: int) -> Optional[np.ndarray]:
        """Sample ``i``'s pressure label (kPa, float32, the crop), or None without force labels."""
        return self._native.pressure(self._index(i))

    def reference(self, i: int) -> Optional[np.ndarray]:
        """The untouched frame sample ``i``'s image is read against (HxWx3 uint8 RGB)."""
        return self._native.reference(self._index(i))

    def __repr__(self) -> str:
        split = "all splits" if self.split is None else f"split {self.split!r}"
        return f"Dataset({self.path!r}, {len(self)} samples, {split})"


def collate(batch: Sequence[Sample]) -> Tuple[Optional[np.ndarray], np.ndarray, List[dict]]:
    """Stacks samples for a ``DataLoader`` (``collate_fn=densetact.collate``): images
    (BxHxWx3 uint8, or None without images), depths (BxHxW float32) and the records as a list
    (records differ in shape, so PyTorch's default collate cannot stack them)."""
    images = [s[0] for s in batch]
    stacked = None if any(i is None for i in images) else np.stack(images)
    return stacked, np.stack([s[1] for s in batch]), [s[2] for s in batch]


class Calibration:
    """What ``calibrate`` found: ``sensor``, the sensor description (save it with ``save`` and
    give it to ``label_session`` or ``dataset label --sensor``), and the figures that say how
    well the frame placed the fisheye (``uncertainty_px``, ``fit_rms_px``, ``edges``, ...)."""

    def __init__(self, sensor: dict, figures: dict) -> None:
        self.sensor = sensor
        self.figures = figures

    def __getattr__(self, name: str) -> Any:
        figures = self.__dict__.get("figures", {})
        if name in figures:
            return figures[name]
        raise AttributeError(name)

    def save(self, path: PathLike) -> None:
        """Writes the sensor description as JSON, atomically (a temporary file, then a rename)."""
        path = os.fspath(path)
        tmp = f"{path}.tmp{os.getpid()}"
        with open(tmp, "w", encoding="utf-8") as f:
            json.dump(self.sensor, f, indent=2)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)

    def __repr__(self) -> str:
        c = self.sensor["correspondence"]
        return (
            f"Calibration(centre ({c['centre_u_px']:.2f}, {c['centre_v_px']:.2f}) px, "
            f"{self.figures['edges']} tooth edges, +-{self.figures['uncertainty_px']:.2f} px)"
        )


def calibrate(
    frame: Union[np.ndarray, PathLike],
    radius_mm: float = 25.0,
    pitch_deg: float = 5.0,
    teeth: int = 17,
    max_uncertainty_px: float = 0.5,
) -> Calibration:
    """Calibrates a unit's fisheye from its camera's frame of the pressed saw-tooth indicator
    (an HxWx3 uint8 RGB array or a path), as ``dataset calibrate`` does. Raises
    ``DenseTactError`` when the frame cannot place the fisheye within ``max_uncertainty_px``."""
    sensor, figures = _densetact.calibrate(frame, radius_mm, pitch_deg, teeth, max_uncertainty_px)
    return Calibration(json.loads(sensor), json.loads(figures))


def label_session(
    session: PathLike,
    sensor: Union[dict, Calibration, PathLike],
    out: PathLike,
    kit: Union[str, PathLike] = "procedural",
    kit_scale: float = 1.0,
    on_bad_row: str = "stop",
    z_from: str = "seated",
    z_zero_mm: Optional[float] = None,
    force_labels: bool = True,
    youngs_modulus_mpa: Optional[float] = None,
    poisson_ratio: Optional[float] = None,
    shard: Optional[str] = None,
    register: bool = False,
) -> Dataset:
    """Labels a capture session (``captures.csv``, its frames, the reference frame) into the
    dataset folder ``out`` with the unit's sensor description (a dict, a ``Calibration`` or a
    JSON file), as ``dataset label`` does: resumable, refusing a folder that is not its own.
    ``shard="K/N"`` labels only share K (0-based) of N of the rows, one task of a job array
    (``dataset merge`` joins the shares). ``register=True`` applies the rig's offsets estimated
    from the log's z sweeps (``dataset label --register``); without it they are reported only.
    Returns the dataset, its ``report`` the lines ``dataset label`` prints."""
    if isinstance(sensor, Calibration):
        sensor = sensor.sensor
    if isinstance(sensor, dict):
        sensor_json = json.dumps(sensor)
    else:
        try:
            with open(os.fspath(sensor), encoding="utf-8") as f:
                sensor_json = f.read()
        except OSError as e:
            raise DenseTactError(f"{os.fspath(sensor)}: cannot read the sensor description: {e.strerror}") from e
    material = {}
    if youngs_modulus_mpa is not None:
        material["youngs_modulus_mpa"] = youngs_modulus_mpa
    if poisson_ratio is not None:
        material["poisson_ratio"] = poisson_ratio
    report = _densetact.label_session(
        os.fspath(session),
        os.fspath(out),
        sensor_json,
        kit=os.fspath(kit),
        kit_scale=kit_scale,
        on_bad_row=on_bad_row,
        z_from=z_from,
        z_zero_mm=z_zero_mm,
        shard=shard,
        register=register,
        force_labels=force_labels,
        **material,
    )
    dataset = Dataset(out)
    dataset.report = list(report)
    return dataset

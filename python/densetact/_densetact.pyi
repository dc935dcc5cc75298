"""Type stubs of the native module (``densetact._densetact``); see ``densetact`` for the guide."""

import os
from typing import List, Optional, Sequence, Tuple, Union

import numpy as np
import numpy.typing as npt

Frame = Union[npt.NDArray[np.uint8], str, "os.PathLike[str]"]

CONTACT_THRESHOLD_MM: float

class DenseTactError(Exception):
    """A densetact operation failed: the message names the file and the problem."""

class Force:
    """A frame's contact force."""

    @property
    def pressure_kpa(self) -> npt.NDArray[np.float32]:
        """Contact pressure (kPa) on the sensor's crop; zero off contact."""
    @property
    def force_n(self) -> npt.NDArray[np.float64]:
        """The force on the sensor (N, sensor frame, x y z): the network's force head's where it
        has one (the pressure then scaled to it), else the pressure's resultant."""
    @property
    def torque_nmm(self) -> npt.NDArray[np.float64]:
        """Its moment about the dome's centre (N mm, sensor frame)."""

class Prediction:
    """Everything one frame gives."""

    @property
    def depth_mm(self) -> npt.NDArray[np.float32]:
        """Depth (mm) on the sensor's crop; zero outside the useful disk."""
    @property
    def contact(self) -> npt.NDArray[np.bool_]:
        """Pixels deeper than ``CONTACT_THRESHOLD_MM``."""
    @property
    def points_mm(self) -> npt.NDArray[np.float32]:
        """The contact patch's surface points, N x 3 (mm, sensor frame)."""
    @property
    def network_ran(self) -> bool:
        """False where the contact gate found no contact (the maps are then zero)."""
    @property
    def force(self) -> Optional[Force]:
        """The contact force, for a bundle with the force output."""

class Predictor:
    """A bundle (``train export``) loaded for prediction, tared on its reference image."""

    def __init__(self, bundle: Union[str, "os.PathLike[str]"], device: str = "cpu") -> None: ...
    def predict(self, frame: Frame, always: bool = False) -> Prediction:
        """One frame (full frame or crop, RGB): bit for bit what ``infer predict`` gives."""
    def predict_batch(self, frames: Sequence[Frame], always: bool = False) -> List[Prediction]:
        """Several frames, those with contact through the network as one batch."""
    def retare(self, frame: Optional[Frame]) -> None:
        """Takes ``frame`` as zero depth from now on; None turns the tare off."""
    def set_reference(self, frame: Frame) -> None:
        """Reads frames against this untouched frame from now on (input, gate, tare)."""
    def has_contact(self, frame: Frame) -> bool:
        """Whether the contact gate sees contact in ``frame``."""
    def set_elastomer(self, effective_modulus_mpa: Optional[float]) -> None:
        """Solves each predicted contact for force with this E / (1 - nu^2) (MPa) from now on;
        None: force only from a network with the force output. Raises ValueError unless > 0."""
    def solve_force(self, depth_mm: npt.NDArray[np.float32]) -> Optional[Force]:
        """The contact a crop-sized depth map shows, solved with the elastomer; None if unsettled."""
    @property
    def effective_modulus_mpa(self) -> Optional[float]:
        """The elastomer predictions are solved with (bundle's or ``set_elastomer``'s), or None."""
    @property
    def bundle(self) -> str: ...
    @property
    def is_tared(self) -> bool: ...
    @property
    def has_force(self) -> bool: ...
    @property
    def force_source(self) -> Optional[str]:
        """Where predictions' force comes from, in words (the force head, the solve, the
        pressure output), or None."""
    @property
    def crop_size_px(self) -> int: ...
    @property
    def crop_origin_px(self) -> Tuple[int, int]:
        """(x, y) of the crop's top-left pixel in the camera's full frame."""
    @property
    def mask(self) -> npt.NDArray[np.bool_]:
        """The useful disk: the crop's pixels that see the dome."""
    @property
    def sensor(self) -> dict:
        """The unit's sensor description."""

class NativeDataset:
    def __init__(self, path: str, split: Optional[str] = None) -> None: ...
    def __len__(self) -> int: ...
    def record_json(self, i: int) -> str: ...
    def image(self, i: int) -> Optional[npt.NDArray[np.uint8]]: ...
    def depth(self, i: int) -> npt.NDArray[np.float32]: ...
    def pressure(self, i: int) -> Optional[npt.NDArray[np.float32]]: ...
    def reference(self, i: int) -> Optional[npt.NDArray[np.uint8]]: ...
    def sensor_json(self) -> str: ...
    @property
    def path(self) -> str: ...

def read_frame(path: Union[str, "os.PathLike[str]"]) -> npt.NDArray[np.uint8]:
    """A camera frame file (PNG or JPEG) as HxWx3 uint8 RGB; damaged files are refused."""

def set_spin_ms(ms: float) -> None:
    """Keep the CPU workers polling ``ms`` ms after each prediction; 0 lets them sleep."""

def calibrate(
    frame: Frame, radius_mm: float = 25.0, pitch_deg: float = 5.0, teeth: int = 17, max_uncertainty_px: float = 0.5
) -> Tuple[str, str]: ...
def label_session(
    session: str,
    out: str,
    sensor_json: str,
    kit: str = "procedural",
    kit_scale: float = 1.0,
    on_bad_row: str = "stop",
    z_from: str = "seated",
    z_zero_mm: Optional[float] = None,
    force_labels: bool = True,
    youngs_modulus_mpa: float = ...,
    poisson_ratio: float = ...,
    shard: Optional[str] = None,
    register: bool = False,
) -> List[str]: ...

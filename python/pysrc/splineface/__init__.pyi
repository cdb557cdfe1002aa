"""Type stubs of splineface (the native module splineface._native, re-exported)."""

import os
from typing import Any, Dict, List, Optional, Sequence, Tuple, Union

from typing_extensions import TypedDict, Unpack, final

__all__ = [
    "BSplineSurface",
    "Face",
    "Landmarker",
    "Reconstruction",
    "SplinefaceError",
    "__version__",
    "batch_subjects",
    "reconstruct",
    "reconstruct_subject",
    "write_demo_photos",
    "write_summary",
]

import numpy as np
import numpy.typing as npt

__version__: str

_Path = Union[str, "os.PathLike[str]"]
_Floats = npt.ArrayLike

class _Settings(TypedDict, total=False):
    """reconstruct's settings (the command line's flags; defaults in brackets)."""

    units: str  # "mm" ["mm"] or "canonical"
    eye_distance: float  # mm between the eye centres, for units="mm" [63]
    shape: str  # "space" ["space"] or "deformed"
    space_noise: float  # the face-space fit's landmark noise, canonical units [4]
    expression_sigma: float  # the prior deviation of each photo's expression [0.5]
    expressions: bool  # fit an expression per photo [True]
    outline: bool  # measure the jaw's landmarks against the face's outline in each photo [True]
    lips: bool  # read an open mouth from the gaps between the inner lips (68-point landmarks) [False]
    refine: bool  # refine with the photos' pixels [True]
    displacement: bool  # with refine, also fit a depth displacement of the control grid [True]
    deformation: str  # "local" ["local"] or "affine", for shape="deformed"
    spacing: float  # mesh vertex spacing, canonical units, 0.1 to 20 [1]
    depth_size: int  # the depth map's larger side, pixels [512]
    texture_size: Optional[int]  # the texture atlas's side, 16 to 8192, or None: from the photos [None]
    min_photos: int  # the fewest usable photos [2]

class SplinefaceError(Exception):
    """A reconstruction, model or file that could not be used; the message names it."""

@final
class BSplineSurface:
    """A tensor-product B-spline surface with a (rows, cols) grid of 3D control points."""

    def __new__(
        cls,
        control_points: _Floats,
        degree_u: int = 3,
        degree_v: int = 3,
        knots_u: Optional[_Floats] = None,
        knots_v: Optional[_Floats] = None,
    ) -> "BSplineSurface":
        """control_points: float64 (rows, cols, 3); knots default to clamped uniform over [0, 1]."""
    @staticmethod
    def fit(
        points: _Floats,
        params: _Floats,
        shape: Tuple[int, int],
        degree: Union[int, Tuple[int, int], None] = None,
        knots_u: Optional[_Floats] = None,
        knots_v: Optional[_Floats] = None,
        weights: Optional[_Floats] = None,
        smoothness: float = 0.0,
    ) -> "BSplineSurface":
        """Least-squares control grid of `shape` for points (n, 3) at params (n, 2)."""
    def eval(self, params: _Floats) -> npt.NDArray[np.float64]:
        """The surface at params (n, 2): (n, 3)."""
    def eval_grid(self, us: _Floats, vs: _Floats) -> npt.NDArray[np.float64]:
        """The surface on the grid us × vs: (len(us), len(vs), 3)."""
    def derivatives(self, params: _Floats, order: int = 1) -> npt.NDArray[np.float64]:
        """(n, order + 1, order + 1, 3): [s, k, l] = d^(k+l) F / du^k dv^l at params[s]."""
    def normal(self, params: _Floats) -> npt.NDArray[np.float64]:
        """Unit normals (n, 3), NaN where the surface is degenerate."""
    def closest(self, points: _Floats) -> dict[str, npt.NDArray[np.float64]]:
        """The closest points to points (n, 3): params (n, 2), points (n, 3), distances (n,)."""
    def to_step(
        self, name: str = "surface", description: str = "", trim: _Floats | None = None, units: str = "mm"
    ) -> str:
        """STEP AP214 text of the exact surface, whole or trimmed to a (u, v) polygon (m, 2);
        the file declares its coordinates to be in `units` ("mm", "cm" or "m")."""
    @property
    def control_points(self) -> npt.NDArray[np.float64]: ...
    @property
    def knots_u(self) -> npt.NDArray[np.float64]: ...
    @property
    def knots_v(self) -> npt.NDArray[np.float64]: ...
    @property
    def degree_u(self) -> int: ...
    @property
    def degree_v(self) -> int: ...
    @property
    def domain_u(self) -> Tuple[float, float]: ...
    @property
    def domain_v(self) -> Tuple[float, float]: ...
    @property
    def fit_report(self) -> Optional[Dict[str, float]]:
        """samples, rms, max, max_index, smoothness of a fitted surface; else None."""
    def to_json(self) -> str: ...
    @staticmethod
    def from_json(text: str) -> "BSplineSurface": ...

@final
class Face:
    """A detected face: box (x, y, width, height), score, 68 iBUG points (68, 2)."""

    @property
    def box(self) -> Tuple[int, int, int, int]: ...
    @property
    def score(self) -> float: ...
    @property
    def disagreement(self) -> float: ...
    @property
    def note(self) -> Optional[str]: ...
    @property
    def points(self) -> npt.NDArray[np.float64]: ...

@final
class Landmarker:
    """dlib's 68-point model (the .dat or splineface's compact form), loaded once."""

    def __new__(cls, model_path: _Path) -> "Landmarker": ...
    def detect(self, image: npt.NDArray[np.uint8]) -> List[Face]:
        """Every face of a uint8 (h, w) or (h, w, 3) RGB image, largest first."""
    def subject(self, image: npt.NDArray[np.uint8]) -> Face:
        """The portrait's subject, as reconstruct picks it; SplinefaceError if none or ambiguous."""

@final
class Reconstruction:
    """A finished reconstruction: arrays, report, and every output file."""

    @property
    def vertices(self) -> npt.NDArray[np.float64]: ...
    @property
    def triangles(self) -> npt.NDArray[np.uint32]: ...
    @property
    def uv(self) -> npt.NDArray[np.float64]: ...
    @property
    def texture(self) -> Optional[npt.NDArray[np.uint8]]: ...
    @property
    def depth(self) -> npt.NDArray[np.float64]: ...
    @property
    def structure(self) -> npt.NDArray[np.float64]: ...
    @property
    def units(self) -> str: ...
    @property
    def poses(self) -> List[Dict[str, Any]]: ...
    @property
    def report(self) -> Dict[str, Any]: ...
    @property
    def photos_used(self) -> List[str]: ...
    @property
    def photos_skipped(self) -> List[str]: ...
    @property
    def files(self) -> List[str]: ...
    def save(self, directory: _Path) -> None:
        """Writes every output file into directory, all or nothing."""

def reconstruct(
    photos: Union[_Path, Sequence[_Path], None] = None,
    landmarks: Optional[_Path] = None,
    landmark_model: Union[_Path, Landmarker, None] = None,
    reference: Optional[_Path] = None,
    *,
    expression_of: Optional[str] = None,
    **settings: Unpack[_Settings],
) -> Reconstruction:
    """A face from photos (a folder, a path or paths; landmarks from files in `landmarks`,
    matched by name, or detected with `landmark_model`), or from a folder of landmark files
    alone. The keywords are the command line's flags."""

def write_demo_photos(directory: _Path, photos: int = 12, noise: float = 1.0, seed: int = 2016) -> List[str]:
    """Writes rendered photos of the embedded demo subject and their landmark files into
    directory (inputs that need no landmark model); returns the files' names."""

def batch_subjects(root: _Path, out: Optional[_Path] = None) -> List[str]:
    """The subject folders of root (its sub-folders); out, if given, must lie outside root."""

def reconstruct_subject(
    folder: _Path,
    out: _Path,
    landmark_model: Union[_Path, Landmarker, None] = None,
    reference: Optional[_Path] = None,
    *,
    force: bool = False,
    **settings: Unpack[_Settings],
) -> Dict[str, Any]:
    """One subject of a batch into out/NAME (skipped when up to date); its summary row. A
    failure is a row with status "failed", never an exception."""

def write_summary(out: _Path, rows: List[Dict[str, Any]]) -> None:
    """summary.csv and summary.jsonl of reconstruct_subject's rows, as splineface batch writes them."""

"""Public value types: `Gaussians`, `Camera`, `RenderOutput`, and the names of the training state's
arrays (`PARAM_NAMES`, the densification statistics `ACCUM` / `COUNT` / `RADII`), shared by the
engine (`reings.state`, `reings.densify`) and the backends' trainers, which import no engine module.

Conventions (fixed; every backend and kernel follows them):

* quaternions are (w, x, y, z), not necessarily unit; they are normalised inside the projection;
* `log_scales` hold log-scales (scale = exp), `opacity_logits` hold logits (opacity = sigmoid);
* `sh` is (N, K, 3) with K in {1, 4, 9, 16} (SH degree 0..3), coefficient order of 3DGS;
* `Camera.K` is the 3x3 pinhole matrix, `Camera.viewmat` the 4x4 world-to-camera matrix with
  OpenCV axes (x right, y down, z forward); pixel (i, j) has its centre at (i + 0.5, j + 0.5).

This module validates shapes and dtypes at the API edge (gsplat's design rule): a wrong shape is
a `ValueError` naming the field, never a kernel failure. Non-finite *values* are allowed: such a
Gaussian is culled by the projection.
"""
from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np

SH_COUNTS = (1, 4, 9, 16)  # K for SH degree 0, 1, 2, 3

# The optimised parameter groups of a training state (reings.state.TrainState), one Adam group each:
#     means [N,3]  quats [N,4]  log_scales [N,3]  opacity_logits [N]  sh_dc [N,1,3]  sh_rest [N,K-1,3]
PARAM_NAMES = ("means", "quats", "log_scales", "opacity_logits", "sh_dc", "sh_rest")

# The densification statistics (reings.densify), per Gaussian, and their dtypes:
#     grad2d_accum  sum of NDC-scaled screen gradient norms over the views that saw the Gaussian
#     grad2d_count  number of those views
#     max_radii2d   largest screen radius seen
ACCUM, COUNT, RADII = "grad2d_accum", "grad2d_count", "max_radii2d"
STAT_DTYPES = {ACCUM: np.float32, COUNT: np.int32, RADII: np.float32}


@dataclass(frozen=True, eq=False)
class RowPlan:
    """A new row set of the training state, made from its old rows (reings.state.apply_index_op
    builds one; the trainers apply it: Trainer.apply_rows, on the device kernels/gather_rows.cl,
    its numpy twin reings.backends.reference_state.apply_rows). New row r:

        parameters  old row src[r] (src[r] < 0: zeros), then, for r >= fresh_start, each
                    parameter named in `fresh` replaced by fresh[name][r - fresh_start]
        moments     old row src[r] for r < n_kept (kept rows), zeros after (new rows)
        statistics  as the moments (every row zero when the trainer is told `zero_stats`)

    src: int64 [n_new]; 0 <= n_kept <= fresh_start <= n_new; fresh: name -> float32 rows
    [n_new - fresh_start, ...]. A row with src < 0 needs every parameter in `fresh`."""

    src: np.ndarray
    n_kept: int
    fresh_start: int
    fresh: dict

    def __len__(self) -> int:
        return len(self.src)

    def then_keep(self, mask) -> "RowPlan":
        """The plan whose rows are this plan's rows where the bool `mask` [len(self)] holds."""
        m = np.asarray(mask)
        if m.dtype != bool or m.shape != (len(self),):
            raise ValueError(f"then_keep: a boolean mask of shape ({len(self)},) expected, got {m.dtype} {m.shape}")
        for k, a in self.fresh.items():
            if len(a) != len(self) - self.fresh_start:
                raise ValueError(f"RowPlan.fresh[{k!r}]: {len(a)} rows, expected {len(self) - self.fresh_start}")
        tail = m[self.fresh_start:]
        return RowPlan(np.asarray(self.src)[m], int(m[:self.n_kept].sum()), int(m[:self.fresh_start].sum()),
                       {k: np.asarray(a)[tail] for k, a in self.fresh.items()})

    def check(self, n_old: int, tails: dict | None = None) -> None:
        """ValueError naming what does not fit a state of `n_old` rows whose parameters have the
        row shapes `tails` (name -> shape after N; None: not checked)."""
        src, n_new = np.asarray(self.src), len(self.src)
        if src.ndim != 1 or src.dtype.kind not in "iu":
            raise ValueError(f"RowPlan.src: an integer vector expected, got {src.dtype} {src.shape}")
        if not 0 <= self.n_kept <= self.fresh_start <= n_new:
            raise ValueError(f"RowPlan: 0 <= n_kept ({self.n_kept}) <= fresh_start ({self.fresh_start}) "
                             f"<= rows ({n_new}) does not hold")
        if n_new and (src.max() >= n_old or (src[:self.fresh_start] < 0).any()):
            raise ValueError(f"RowPlan.src: rows outside [0, {n_old}) (only rows from fresh_start may have none)")
        for k, a in self.fresh.items():
            if k not in PARAM_NAMES:
                raise ValueError(f"RowPlan.fresh: unknown parameter {k!r}")
            if len(a) != n_new - self.fresh_start:
                raise ValueError(f"RowPlan.fresh[{k!r}]: {len(a)} rows, expected {n_new - self.fresh_start}")
            if tails is not None and tuple(np.shape(a)[1:]) != tuple(tails[k]):
                raise ValueError(f"RowPlan.fresh[{k!r}]: rows of shape {np.shape(a)[1:]}, expected {tuple(tails[k])}")
        if (src[self.fresh_start:] < 0).any() and set(self.fresh) != set(PARAM_NAMES):
            raise ValueError("RowPlan: rows without a source need every parameter in `fresh`")


def _as_f32(name: str, a) -> np.ndarray:
    try:
        return np.ascontiguousarray(np.asarray(a, dtype=np.float32))
    except (TypeError, ValueError) as e:  # strings, objects, ragged lists
        raise ValueError(f"Gaussians.{name}: expected an array of numbers ({e})") from None


def _f32(name: str, a, shape_tail: tuple, lead: int | None = None) -> np.ndarray:
    a = _as_f32(name, a)
    want = len(shape_tail) + 1
    if a.ndim != want or tuple(a.shape[1:]) != shape_tail or (lead is not None and a.shape[0] != lead):
        exp = ("N" if lead is None else str(lead),) + tuple(str(s) for s in shape_tail)
        raise ValueError(f"Gaussians.{name}: expected shape ({', '.join(exp)}), got {a.shape}")
    return a


@dataclass(frozen=True)
class Gaussians:
    """N Gaussians as float32 numpy arrays (raw, un-activated parameters)."""

    means: np.ndarray  # [N, 3]
    quats: np.ndarray  # [N, 4] (w, x, y, z), any norm
    log_scales: np.ndarray  # [N, 3]
    opacity_logits: np.ndarray  # [N]
    sh: np.ndarray  # [N, K, 3], K in {1, 4, 9, 16}

    def __post_init__(self):
        means = _f32("means", self.means, (3,))
        n = means.shape[0]
        object.__setattr__(self, "means", means)
        object.__setattr__(self, "quats", _f32("quats", self.quats, (4,), n))
        object.__setattr__(self, "log_scales", _f32("log_scales", self.log_scales, (3,), n))
        op = _as_f32("opacity_logits", self.opacity_logits)
        if op.shape != (n,):
            raise ValueError(f"Gaussians.opacity_logits: expected shape ({n},), got {op.shape}")
        object.__setattr__(self, "opacity_logits", op)
        sh = _as_f32("sh", self.sh)
        if sh.ndim != 3 or sh.shape[0] != n or sh.shape[2] != 3 or sh.shape[1] not in SH_COUNTS:
            raise ValueError(f"Gaussians.sh: expected shape ({n}, K, 3) with K in {SH_COUNTS}, got {sh.shape}")
        object.__setattr__(self, "sh", sh)

    def __len__(self) -> int:
        return self.means.shape[0]

    @property
    def sh_degree(self) -> int:
        return SH_COUNTS.index(self.sh.shape[1])

    @classmethod
    def empty(cls, sh_degree: int = 0) -> "Gaussians":
        k = SH_COUNTS[sh_degree]
        z = np.zeros
        return cls(z((0, 3)), z((0, 4)), z((0, 3)), z((0,)), z((0, k, 3)))

    def zeros_like(self) -> "Gaussians":
        return Gaussians(*(np.zeros_like(getattr(self, f.name)) for f in fields(self)))

    def astuple(self) -> tuple:
        return tuple(getattr(self, f.name) for f in fields(self))

    def subset(self, index) -> "Gaussians":
        """Rows selected by an index array or boolean mask."""
        return Gaussians(*(a[index] for a in self.astuple()))


FIELDS = tuple(f.name for f in fields(Gaussians))  # ("means", "quats", ...)


@dataclass(frozen=True)
class Camera:
    """Pinhole camera: K [3, 3], viewmat [4, 4] world-to-camera (OpenCV axes), image size in pixels."""

    K: np.ndarray  # [3, 3] [[fx, 0, cx], [0, fy, cy], [0, 0, 1]]
    viewmat: np.ndarray  # [4, 4]
    width: int
    height: int

    def __post_init__(self):
        K = np.asarray(self.K, dtype=np.float64)
        V = np.asarray(self.viewmat, dtype=np.float64)
        if K.shape != (3, 3):
            raise ValueError(f"Camera.K: expected shape (3, 3), got {K.shape}")
        if V.shape != (4, 4):
            raise ValueError(f"Camera.viewmat: expected shape (4, 4), got {V.shape}")
        if not (np.all(np.isfinite(K)) and np.all(np.isfinite(V))):
            raise ValueError("Camera: K and viewmat must be finite")
        if not (K[0, 0] > 0 and K[1, 1] > 0):
            raise ValueError(f"Camera.K: focal lengths must be positive, got fx={K[0, 0]}, fy={K[1, 1]}")
        w, h = int(self.width), int(self.height)
        if w != self.width or h != self.height or w < 1 or h < 1:
            raise ValueError(f"Camera: width and height must be positive integers, got {self.width}x{self.height}")
        object.__setattr__(self, "K", K)
        object.__setattr__(self, "viewmat", V)
        object.__setattr__(self, "width", w)
        object.__setattr__(self, "height", h)

    @property
    def fx(self) -> float:
        return float(self.K[0, 0])

    @property
    def fy(self) -> float:
        return float(self.K[1, 1])

    @property
    def cx(self) -> float:
        return float(self.K[0, 2])

    @property
    def cy(self) -> float:
        return float(self.K[1, 2])

    @property
    def center(self) -> np.ndarray:
        """Camera centre in world coordinates, [3] float64."""
        R, t = self.viewmat[:3, :3], self.viewmat[:3, 3]
        return -R.T @ t


@dataclass
class RenderOutput:
    """What `reings.render` returns. All float32 numpy arrays."""

    rgb: np.ndarray  # [H, W, 3]  colour + T_final * background
    depth: np.ndarray  # [H, W]   sum of t_z * alpha * T (not normalised by alpha)
    alpha: np.ndarray  # [H, W]   sum of alpha * T
    final_T: np.ndarray | None = None  # [H, W] transmittance left after the last blended Gaussian
    importance: np.ndarray | None = None  # [N] per-Gaussian sum of alpha*T over pixels (if asked)
    stats: dict | None = None  # counts: visible, intersections, evaluated pairs, ...

"""The float64 numpy reference backend: the living definition every OpenCL kernel is tested against.

Written for reading, not speed. Each stage of `base.py` is one function here with the same name:

    project_fwd -> bin -> rasterize_fwd            (forward)
    rasterize_bwd -> project_bwd                   (backward; `isect_reduce` is the np.add.at inside
                                                    rasterize_bwd)

Inputs may be a float32 `reings.Gaussians` or a float64 `Params64` (same field names; the FD tests
need float64 parameters, which `Gaussians` would round to float32). Everything is computed in
float64; indices are int32. The hand-written backward is checked by central finite differences in
`tests/test_reference_fd.py`.

Conventions decided here (the issue's §3 leaves them open):

* Culling. A Gaussian is culled (radii 0, zero row) if any raw field is non-finite; if its quaternion
  norm is below QUAT_NORM_MIN = 1e-12; if t_z <= near; if det(Σ2D) <= 0; if its tile rect is empty;
  or if any projected value (means2d, conic, Σ2D, λ_max, depth, colour, opacity) is non-finite
  *or not representable in float32* (|x| > FLT_MAX): the float32 device would see inf there.
* A Gaussian exactly at the camera centre has t = 0, so t_z = 0 <= near and it is culled by the near
  test before its (undefined) SH direction matters. The SH code still guards |μ - centre| == 0 by
  using direction (0, 0, 1), so no NaN can appear whatever `near` is.
* Radii are int32: r = ceil(3 sqrt(λ_max)) saturated at 2**31 - 1 (the tile rect is clamped anyway).
* Tile rect (opacity-aware; `alpha_box_rect`, kernels/project.cl `alpha_rect`): the tiles of the
  square (u ± r, v ± r), clamped to the grid, cut to the tiles overlapped by the alpha box of the
  opacity o (the rasterizer's box outside of which o·exp(power) < 1/255, half-widths
  sqrt(2 ln(255 o) C / det)·1.01·(1 + 2⁻¹²) + 0.5 px along x, A for y, det = AC − B² of the conic);
  the 3-sigma tiles stay where that box is ill-conditioned (det < 2⁻⁸ AC, AC < 2⁻¹⁰⁰, not positive
  definite, 255 o not finite). o < 1/255 gives an empty rect (all zeros) but no culling: radii and
  the other fields are kept. The cut removes only pairs that blend nothing, so images and gradients
  are those of the 3-sigma rect. `alpha_min` on project_fwd is the rasterizer's test-only knob (the
  box is that of alpha_min; alpha_min <= 0: no cut, the 3-sigma rect).
* DropGaussian (`drop=`, a reference_drop.Drop; docs/method.md §9): the Gaussians the mask drops are
  culled like invisible ones; a kept one's opacity is sigmoid(logit) * drop.scale (may exceed 1;
  the α clamp below bounds each pair), and its logit gradient carries the same factor.
* tile_ranges for an empty tile t: [s, s) with s = number of intersections in tiles < t
  (numpy.searchsorted semantics, like gsplat's isect_offset_encode).
* Alpha clamp: gradient flows iff opacity * exp(power) <= ALPHA_MAX (gsplat's `<=`); the clamped
  branch has zero gradient. Colour clamp: gradient flows iff SH + 0.5 >= 0 (3DGS's `result < 0`).
* Jacobian clamp: the clamped axis gets zero gradient through x/t_z (resp. y/t_z); J still depends
  on t_z explicitly (J02 = -fx * clamp(x/t_z) / t_z), and that derivative is kept. This is the exact
  derivative of the forward function (gsplat instead differentiates J02 = -fx*tx/tz^2 with tx fixed,
  which differs by a factor 2 in that one term when the clamp is active).
* Backward order: per pixel, transmittances are recomputed front to back (exclusive cumulative
  products, no division), and the "everything behind k" terms come from suffix sums; this is the
  same function as the back-to-front walk with T recovered by division.
* stats["evaluated_pairs"]: per pixel, the list entries examined up to and including the one that
  triggered the early stop (all entries if none did), summed over pixels.

`alpha_min` on the rasterize stages, project_fwd (its opacity-aware tile rect) and render64 is a
TEST-ONLY knob (default ALPHA_MIN): the FD tests pass 0 to remove the 1/255 skip discontinuity.
"""
from __future__ import annotations

from dataclasses import dataclass, fields
from typing import Sequence

import numpy as np

from ..types import FIELDS, SH_COUNTS, Camera, Gaussians, RenderOutput
from .reference_drop import Drop
from .reference_loss import depth_loss as _depth_loss
from .reference_loss import photometric_loss as _photometric_loss
from .base import (ALPHA_MAX, ALPHA_MIN, CLAMP_GUARD, EPS2D, T_MIN, TILE_SIZE, Bins, Projected,
                   RasterGrads, RasterOut, bin_problem, bins_problem, select_engine, tile_grid)

QUAT_NORM_MIN = 1e-12  # quaternion norm below this: rotation undefined, cull
FLT_MAX = float(np.finfo(np.float32).max)
INT32_MAX = 2**31 - 1
LAMBDA_FLOOR = 0.1  # λ_max = mid + sqrt(max(0.1, mid² - det)) (3DGS)
ALPHA_BOX_REL, ALPHA_BOX_PAD = 1.01, 0.5  # the alpha box's room (kernels/common.h)
BOX_SLACK = 1.0 + 2.0**-12  # project_fwd's box is this much wider (kernels/project.cl PROJ_BOX_SLACK)
BOX_COND, BOX_AC_MIN = 2.0**-8, 2.0**-100  # the box only where det >= BOX_COND AC, AC >= BOX_AC_MIN


# ----------------------------------------------------------------------------------------------
# float64 parameter container
# ----------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Params64:
    """Same fields as `reings.Gaussians`, kept in float64 (used for FD tests and for gradients)."""

    means: np.ndarray  # [N, 3]
    quats: np.ndarray  # [N, 4] (w, x, y, z)
    log_scales: np.ndarray  # [N, 3]
    opacity_logits: np.ndarray  # [N]
    sh: np.ndarray  # [N, K, 3]

    def __len__(self) -> int:
        return self.means.shape[0]

    @property
    def sh_degree(self) -> int:
        return SH_COUNTS.index(self.sh.shape[1])

    def astuple(self) -> tuple:
        return tuple(getattr(self, f.name) for f in fields(self))

    def replace(self, **kw) -> "Params64":
        d = {f: getattr(self, f) for f in FIELDS}
        d.update(kw)
        return Params64(**d)

    def copy(self) -> "Params64":
        return Params64(*(np.array(a, dtype=np.float64, copy=True) for a in self.astuple()))

    def zeros_like(self) -> "Params64":
        return Params64(*(np.zeros_like(a) for a in self.astuple()))

    def to_gaussians(self) -> Gaussians:
        """float32 `Gaussians` (values beyond float32 range become ±inf)."""
        with np.errstate(over="ignore"):
            return Gaussians(*(a.astype(np.float32) for a in self.astuple()))

    @classmethod
    def of(cls, g) -> "Params64":
        """float64 copy of anything with the five Gaussians fields."""
        if isinstance(g, Params64):
            return g
        return cls(*(np.asarray(getattr(g, f), dtype=np.float64) for f in FIELDS))


# ----------------------------------------------------------------------------------------------
# Spherical harmonics (docs/method.md §5.5): basis, its Jacobian in the direction, colour and VJP
# ----------------------------------------------------------------------------------------------
SH_C0 = 0.28209479177387814
SH_C1 = 0.4886025119029199
SH_C2 = (1.0925484305920792, -1.0925484305920792, 0.31539156525252005, -1.0925484305920792,
         0.5462742152960396)
SH_C3 = (-0.5900435899266435, 2.890611442640554, -0.4570457994644658, 0.3731763325901154,
         -0.4570457994644658, 1.445305721320277, -0.5900435899266435)


def sh_basis(dirs: np.ndarray, degree: int, with_jacobian: bool = False):
    """Real SH basis of 3DGS at directions `dirs` [N, 3] (used as given, not renormalised).

    Returns basis [N, K] (K = (degree+1)²) and, if asked, its Jacobian d basis / d dir [N, K, 3]
    (x, y, z treated as independent; the caller chains through the normalisation).
    """
    dirs = np.asarray(dirs, dtype=np.float64)
    n = dirs.shape[0]
    k = SH_COUNTS[degree]
    x, y, z = dirs[:, 0], dirs[:, 1], dirs[:, 2]
    one, zero = np.ones(n), np.zeros(n)
    b = [SH_C0 * one]
    jac = [(zero, zero, zero)]
    if degree >= 1:
        b += [-SH_C1 * y, SH_C1 * z, -SH_C1 * x]
        jac += [(zero, -SH_C1 * one, zero), (zero, zero, SH_C1 * one), (-SH_C1 * one, zero, zero)]
    if degree >= 2:
        xx, yy, zz = x * x, y * y, z * z
        c = SH_C2
        b += [c[0] * x * y, c[1] * y * z, c[2] * (2 * zz - xx - yy), c[3] * x * z, c[4] * (xx - yy)]
        jac += [(c[0] * y, c[0] * x, zero),
                (zero, c[1] * z, c[1] * y),
                (-2 * c[2] * x, -2 * c[2] * y, 4 * c[2] * z),
                (c[3] * z, zero, c[3] * x),
                (2 * c[4] * x, -2 * c[4] * y, zero)]
    if degree >= 3:
        c = SH_C3
        b += [c[0] * y * (3 * xx - yy),
              c[1] * x * y * z,
              c[2] * y * (4 * zz - xx - yy),
              c[3] * z * (2 * zz - 3 * xx - 3 * yy),
              c[4] * x * (4 * zz - xx - yy),
              c[5] * z * (xx - yy),
              c[6] * x * (xx - 3 * yy)]
        jac += [(6 * c[0] * x * y, c[0] * (3 * xx - 3 * yy), zero),
                (c[1] * y * z, c[1] * x * z, c[1] * x * y),
                (-2 * c[2] * x * y, c[2] * (4 * zz - xx - 3 * yy), 8 * c[2] * y * z),
                (-6 * c[3] * x * z, -6 * c[3] * y * z, c[3] * (6 * zz - 3 * xx - 3 * yy)),
                (c[4] * (4 * zz - 3 * xx - yy), -2 * c[4] * x * y, 8 * c[4] * x * z),
                (2 * c[5] * x * z, -2 * c[5] * y * z, c[5] * (xx - yy)),
                (c[6] * (3 * xx - 3 * yy), -6 * c[6] * x * y, zero)]
    basis = np.stack(b[:k], axis=1)  # [N, K]
    if not with_jacobian:
        return basis
    J = np.stack([np.stack(j, axis=1) for j in jac[:k]], axis=1)  # [N, K, 3]
    return basis, J


def sh_to_color(sh: np.ndarray, dirs: np.ndarray) -> np.ndarray:
    """Σ_k basis_k(dir) sh_k + 0.5, clamped at 0. sh [N, K, 3], dirs [N, 3] unit. Returns [N, 3]."""
    sh = np.asarray(sh, dtype=np.float64)
    basis = sh_basis(dirs, SH_COUNTS.index(sh.shape[1]))
    return np.maximum(np.einsum("nk,nkc->nc", basis, sh) + 0.5, 0.0)


def sh_to_color_vjp(sh: np.ndarray, dirs: np.ndarray, v_colors: np.ndarray):
    """VJP of `sh_to_color`: returns (v_sh [N, K, 3], v_dirs [N, 3]) (v_dirs for the un-normalised
    polynomial basis; chain through the normalisation separately). Clamped channels get zero."""
    sh = np.asarray(sh, dtype=np.float64)
    basis, J = sh_basis(dirs, SH_COUNTS.index(sh.shape[1]), with_jacobian=True)
    raw = np.einsum("nk,nkc->nc", basis, sh) + 0.5
    v_raw = np.where(raw >= 0.0, v_colors, 0.0)  # [N, 3]
    v_sh = basis[:, :, None] * v_raw[:, None, :]
    v_dirs = np.einsum("nkd,nkc,nc->nd", J, sh, v_raw)
    return v_sh, v_dirs


# ----------------------------------------------------------------------------------------------
# Quaternion -> rotation and its VJP
# ----------------------------------------------------------------------------------------------
def quat_to_rotmat(q: np.ndarray) -> np.ndarray:
    """Unit quaternions (w, x, y, z) [N, 4] -> rotation matrices [N, 3, 3] (standard matrix)."""
    w, x, y, z = q[:, 0], q[:, 1], q[:, 2], q[:, 3]
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
        np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
        np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
    ], axis=1)


def quat_to_rotmat_vjp(q: np.ndarray, v_R: np.ndarray) -> np.ndarray:
    """VJP of `quat_to_rotmat` (as a polynomial in the 4 components): returns v_q [N, 4]."""
    w, x, y, z = q[:, 0], q[:, 1], q[:, 2], q[:, 3]
    g = v_R
    v_w = 2 * (-z * g[:, 0, 1] + y * g[:, 0, 2] + z * g[:, 1, 0] - x * g[:, 1, 2] - y * g[:, 2, 0] + x * g[:, 2, 1])
    v_x = 2 * (y * g[:, 0, 1] + z * g[:, 0, 2] + y * g[:, 1, 0] - 2 * x * g[:, 1, 1] - w * g[:, 1, 2]
               + z * g[:, 2, 0] + w * g[:, 2, 1] - 2 * x * g[:, 2, 2])
    v_y = 2 * (-2 * y * g[:, 0, 0] + x * g[:, 0, 1] + w * g[:, 0, 2] + x * g[:, 1, 0] + z * g[:, 1, 2]
               - w * g[:, 2, 0] + z * g[:, 2, 1] - 2 * y * g[:, 2, 2])
    v_z = 2 * (-2 * z * g[:, 0, 0] - w * g[:, 0, 1] + x * g[:, 0, 2] + w * g[:, 1, 0] - 2 * z * g[:, 1, 1]
               + y * g[:, 1, 2] + x * g[:, 2, 0] + y * g[:, 2, 1])
    return np.stack([v_w, v_x, v_y, v_z], axis=1)


# ----------------------------------------------------------------------------------------------
# project_fwd / project_bwd
# ----------------------------------------------------------------------------------------------
def _finite32(a: np.ndarray) -> np.ndarray:
    """Row mask: every value finite and representable in float32."""
    a = a.reshape(a.shape[0], int(np.prod(a.shape[1:])))
    return np.all(np.isfinite(a) & (np.abs(a) <= FLT_MAX), axis=1)


def alpha_box_rect(rect: np.ndarray, means2d: np.ndarray, conics: np.ndarray, opacities: np.ndarray,
                   alpha_min: float = ALPHA_MIN) -> np.ndarray:
    """The opacity-aware tile rect (module docstring): `rect` [N, 4] (the 3-sigma tiles, clamped to
    the grid) cut to the tiles overlapped by the alpha box of each row's (u, v), conic and opacity;
    rows with opacity < alpha_min get all zeros. alpha_min <= 0: `rect` unchanged."""
    rect = np.array(rect, dtype=np.float64, copy=True)
    if not alpha_min > 0:
        return rect
    with np.errstate(all="ignore"):
        A, B, C = conics[:, 0], conics[:, 1], conics[:, 2]
        lo = opacities / alpha_min
        ac = A * C
        det = ac - B * B
        box = ((lo >= 1.0) & (lo <= FLT_MAX) & (A > 0) & (C > 0) & (det > 0) & (det <= FLT_MAX)
               & (det >= BOX_COND * ac) & (ac >= BOX_AC_MIN))
        thr = 2.0 * np.log(np.where(box, lo, 1.0))
        dets = np.where(box, det, 1.0)
        ex = np.sqrt(thr * C / dets) * (ALPHA_BOX_REL * BOX_SLACK) + ALPHA_BOX_PAD
        ey = np.sqrt(thr * A / dets) * (ALPHA_BOX_REL * BOX_SLACK) + ALPHA_BOX_PAD
        u, v = means2d[:, 0], means2d[:, 1]
        cut = np.stack([np.floor(np.ceil(u - ex - 0.5) / TILE_SIZE), np.floor(np.ceil(v - ey - 0.5) / TILE_SIZE),
                        np.floor(np.floor(u + ex - 0.5) / TILE_SIZE) + 1,
                        np.floor(np.floor(v + ey - 0.5) / TILE_SIZE) + 1], axis=1)
        out = np.concatenate([np.maximum(rect[:, :2], cut[:, :2]), np.minimum(rect[:, 2:], cut[:, 2:])], axis=1)
        out = np.where(box[:, None], out, rect)
        empty = (lo < 1.0) | ~((out[:, 2] > out[:, 0]) & (out[:, 3] > out[:, 1]))
    return np.where(empty[:, None], 0.0, out)


def _project(g, cam: Camera, near: float, opacity_override, drop: Drop | None = None,
             alpha_min: float = ALPHA_MIN):
    """project_fwd plus the intermediates project_bwd needs (dict)."""
    p = Params64.of(g)
    n = len(p)
    if drop is not None and opacity_override is not None:
        raise ValueError("project: a DropGaussian mask is never combined with an opacity override")
    scale = 1.0 if drop is None else float(drop.scale)
    W, H = cam.width, cam.height
    fx, fy, cx, cy = cam.fx, cam.fy, cam.cx, cam.cy
    Rc, tc = cam.viewmat[:3, :3], cam.viewmat[:3, 3]
    tiles_x, tiles_y = tile_grid(W, H)
    with np.errstate(all="ignore"):
        ok = (_finite32(p.means) & _finite32(p.quats) & _finite32(p.log_scales)
              & _finite32(p.opacity_logits[:, None]) & _finite32(p.sh))
        if drop is not None:  # DropGaussian: a dropped Gaussian is culled (reference_drop)
            ok &= drop.kept(n)
        # quaternion -> rotation
        qnorm = np.sqrt(np.sum(p.quats**2, axis=1))  # [N]
        ok &= qnorm >= QUAT_NORM_MIN
        qn = np.where(ok[:, None], p.quats / np.where(ok, qnorm, 1.0)[:, None], [1.0, 0, 0, 0])
        R = quat_to_rotmat(qn)  # [N, 3, 3]
        s = np.where(ok[:, None], np.exp(p.log_scales), 1.0)  # [N, 3]
        M = R * s[:, None, :]  # R S
        Sigma = M @ np.swapaxes(M, 1, 2)  # [N, 3, 3]
        # camera space
        means = np.where(ok[:, None], p.means, 0.0)
        t = means @ Rc.T + tc  # [N, 3]
        ok &= t[:, 2] > near
        tz = np.where(ok, t[:, 2], 1.0)
        tx, ty = t[:, 0], t[:, 1]
        # Jacobian with gsplat's guard-band clamp
        tan_fovx, tan_fovy = 0.5 * W / fx, 0.5 * H / fy
        lim_xp, lim_xn = (W - cx) / fx + CLAMP_GUARD * tan_fovx, cx / fx + CLAMP_GUARD * tan_fovx
        lim_yp, lim_yn = (H - cy) / fy + CLAMP_GUARD * tan_fovy, cy / fy + CLAMP_GUARD * tan_fovy
        xr, yr = tx / tz, ty / tz
        xc, yc = np.clip(xr, -lim_xn, lim_xp), np.clip(yr, -lim_yn, lim_yp)
        mask_x = (xr >= -lim_xn) & (xr <= lim_xp)  # 1: J depends on x through x/t_z
        mask_y = (yr >= -lim_yn) & (yr <= lim_yp)
        J = np.zeros((n, 2, 3))
        J[:, 0, 0] = fx / tz
        J[:, 0, 2] = -fx * xc / tz
        J[:, 1, 1] = fy / tz
        J[:, 1, 2] = -fy * yc / tz
        Sc = Rc @ Sigma @ Rc.T  # [N, 3, 3]
        S2 = J @ Sc @ np.swapaxes(J, 1, 2) + EPS2D * np.eye(2)  # [N, 2, 2]
        a, b, c = S2[:, 0, 0], S2[:, 0, 1], S2[:, 1, 1]
        det = a * c - b * b
        ok &= det > 0
        dets = np.where(ok, det, 1.0)
        conics = np.stack([c / dets, -b / dets, a / dets], axis=1)
        mid = 0.5 * (a + c)
        lam = mid + np.sqrt(np.maximum(LAMBDA_FLOOR, mid * mid - det))
        r = np.ceil(3.0 * np.sqrt(lam))
        u, v = fx * tx / tz + cx, fy * ty / tz + cy
        means2d = np.stack([u, v], axis=1)
        # SH colour at normalize(μ - camera centre)
        d = means - cam.center
        dn = np.sqrt(np.sum(d * d, axis=1))
        at_centre = ~(dn > 0)
        dirs = np.where(at_centre[:, None], [0.0, 0.0, 1.0], d / np.where(at_centre, 1.0, dn)[:, None])
        sh = np.where(ok[:, None, None], p.sh, 0.0)
        basis = sh_basis(dirs, p.sh_degree)
        raw = np.einsum("nk,nkc->nc", basis, sh) + 0.5
        colors = np.maximum(raw, 0.0)
        sig = 1.0 / (1.0 + np.exp(-p.opacity_logits))
        if opacity_override is None:
            opac = sig * scale  # DropGaussian's compensation 1 / (1 - rate) (1 without a drop)
        else:
            opac = np.full(n, float(opacity_override))
        ok &= (_finite32(means2d) & _finite32(conics) & _finite32(S2) & _finite32(lam[:, None])
               & _finite32(t) & _finite32(colors) & _finite32(opac[:, None]))
        # tile rect, clamped to the grid (computed in float, clamped before the int cast)
        rs = np.where(ok, r, 0.0)
        us, vs = np.where(ok, u, 0.0), np.where(ok, v, 0.0)
        tx0 = np.clip(np.floor((us - rs) / TILE_SIZE), 0, tiles_x)
        tx1 = np.clip(np.ceil((us + rs) / TILE_SIZE), 0, tiles_x)
        ty0 = np.clip(np.floor((vs - rs) / TILE_SIZE), 0, tiles_y)
        ty1 = np.clip(np.ceil((vs + rs) / TILE_SIZE), 0, tiles_y)
        ok &= (tx1 > tx0) & (ty1 > ty0)
    # the opacity-aware cut: never culls (radii kept)
    rect = alpha_box_rect(np.stack([tx0, ty0, tx1, ty1], axis=1), means2d, conics, opac, alpha_min)

    z = lambda arr: np.where(ok.reshape((-1,) + (1,) * (arr.ndim - 1)), arr, 0.0)  # noqa: E731
    proj = Projected(
        means2d=z(means2d),
        conics=z(conics),
        depths=z(tz),
        radii=np.where(ok, np.minimum(rs, INT32_MAX), 0).astype(np.int32),
        tile_rect=np.where(ok[:, None], rect, 0).astype(np.int32),
        colors=z(colors),
        opacities=z(opac),
    )
    aux = dict(p=p, ok=ok, qn=qn, qnorm=qnorm, R=R, s=s, M=M, t=t, tz=tz, xc=xc, yc=yc,
               mask_x=mask_x, mask_y=mask_y, J=J, Sc=Sc, S2=S2, dets=dets, dirs=dirs, dn=dn,
               at_centre=at_centre, raw=raw, opac=opac, sig=sig, scale=scale)
    return proj, aux


def project_fwd(g, cam: Camera, near: float = 0.01, opacity_override: float | None = None,
                drop: Drop | None = None, alpha_min: float = ALPHA_MIN) -> Projected:
    """Project N Gaussians (float32 `Gaussians` or float64 `Params64`) to screen space.

    drop: DropGaussian's mask (reference_drop.Drop; None: none): the Gaussians it drops are
    culled, the kept ones' opacities are sigmoid(logit) * drop.scale. Never with an override.
    alpha_min: the test-only knob of the rasterizer (its alpha box cuts the tile rect; <= 0: the
    3-sigma rect). Returns `Projected` (float64 fields, int32 radii / tile_rect); culled rows are
    zero; a visible row with opacity < alpha_min has an empty (all-zero) tile_rect.
    """
    return _project(g, cam, near, opacity_override, drop, alpha_min)[0]


def project_bwd(g, cam: Camera, proj: Projected, grads: RasterGrads, near: float = 0.01,
                opacity_override: float | None = None, drop: Drop | None = None) -> Params64:
    """VJP of `project_fwd`: cotangents of the projected fields -> dL/d(raw field), float64
    `Params64` (same field names as `Gaussians`). `proj` is accepted for the stage signature; the
    intermediates are recomputed from `g`. Culled Gaussians (dropped ones included) get zero
    gradient; with a drop the opacity-logit gradient carries the factor drop.scale."""
    _, ax = _project(g, cam, near, opacity_override, drop)
    p, ok = ax["p"], ax["ok"]
    n = len(p)
    fx, fy = cam.fx, cam.fy
    Rc = cam.viewmat[:3, :3]
    okc = ok[:, None]
    v_m2d = np.where(okc, np.asarray(grads.v_means2d, np.float64), 0.0)
    v_con = np.where(okc, np.asarray(grads.v_conics, np.float64), 0.0)
    v_col = np.where(okc, np.asarray(grads.v_colors, np.float64), 0.0)
    v_opa = np.where(ok, np.asarray(grads.v_opacities, np.float64), 0.0)
    v_dep = np.where(ok, np.asarray(grads.v_depths, np.float64), 0.0)

    t, tz, J, Sc, S2 = ax["t"], ax["tz"], ax["J"], ax["Sc"], ax["S2"]
    tx, ty = t[:, 0], t[:, 1]
    with np.errstate(all="ignore"):
        # conic = S2^-1:  dL/dS2 = -S2^-1 G S2^-1, G the symmetric cotangent of the inverse
        Sinv = np.linalg.inv(np.where(ok[:, None, None], S2, np.eye(2)))
        G = np.stack([np.stack([v_con[:, 0], 0.5 * v_con[:, 1]], -1),
                      np.stack([0.5 * v_con[:, 1], v_con[:, 2]], -1)], axis=1)
        v_S2 = -Sinv @ G @ Sinv  # [N, 2, 2]
        # S2 = J Sc J^T + eps I
        Jt = np.swapaxes(J, 1, 2)
        v_Sc = Jt @ v_S2 @ J  # [N, 3, 3]
        v_J = v_S2 @ J @ np.swapaxes(Sc, 1, 2) + np.swapaxes(v_S2, 1, 2) @ J @ Sc  # [N, 2, 3]
        # J entries: J00 = fx/tz, J02 = -fx xc/tz, J11 = fy/tz, J12 = -fy yc/tz
        v_t = np.zeros((n, 3))
        v_xc = v_J[:, 0, 2] * (-fx / tz)
        v_yc = v_J[:, 1, 2] * (-fy / tz)
        mx, my = ax["mask_x"].astype(np.float64), ax["mask_y"].astype(np.float64)
        v_t[:, 0] += v_xc * mx / tz
        v_t[:, 1] += v_yc * my / tz
        v_t[:, 2] += (-v_xc * mx * tx / tz**2 - v_yc * my * ty / tz**2
                      - v_J[:, 0, 0] * fx / tz**2 - v_J[:, 1, 1] * fy / tz**2
                      + v_J[:, 0, 2] * fx * ax["xc"] / tz**2 + v_J[:, 1, 2] * fy * ax["yc"] / tz**2)
        # means2d: u = fx tx/tz + cx, v = fy ty/tz + cy
        v_t[:, 0] += fx / tz * v_m2d[:, 0]
        v_t[:, 1] += fy / tz * v_m2d[:, 1]
        v_t[:, 2] += -(fx * tx * v_m2d[:, 0] + fy * ty * v_m2d[:, 1]) / tz**2
        # depth
        v_t[:, 2] += v_dep
        v_t = np.where(okc, v_t, 0.0)
        # t = Rc μ + tc
        v_means = v_t @ Rc
        # Sc = Rc Σ Rc^T;  Σ = M M^T, M = R S
        v_Sigma = Rc.T @ v_Sc @ Rc
        v_M = (v_Sigma + np.swapaxes(v_Sigma, 1, 2)) @ ax["M"]
        s, R = ax["s"], ax["R"]
        v_R = v_M * s[:, None, :]
        v_s = np.sum(v_M * R, axis=1)  # [N, 3]
        v_log_scales = v_s * s
        # normalised quaternion
        v_qn = quat_to_rotmat_vjp(ax["qn"], v_R)
        qn = ax["qn"]
        qnorm = np.where(ok, ax["qnorm"], 1.0)
        v_quats = (v_qn - qn * np.sum(qn * v_qn, axis=1, keepdims=True)) / qnorm[:, None]
        # SH colour (incl. its dependence on μ through the direction)
        sh = np.where(ok[:, None, None], p.sh, 0.0)
        v_sh, v_dirs = sh_to_color_vjp(sh, ax["dirs"], v_col)
        dirs = ax["dirs"]
        dn = np.where(ax["at_centre"], 1.0, ax["dn"])
        v_d = (v_dirs - dirs * np.sum(dirs * v_dirs, axis=1, keepdims=True)) / dn[:, None]
        v_d[ax["at_centre"]] = 0.0
        v_means += v_d
        # opacity
        if opacity_override is None:
            o = ax["sig"]  # opacity = scale * sigmoid(logit)
            v_logits = v_opa * o * (1.0 - o) * ax["scale"]
        else:
            v_logits = np.zeros(n)

    z = lambda arr: np.where(ok.reshape((-1,) + (1,) * (arr.ndim - 1)), arr, 0.0)  # noqa: E731
    return Params64(z(v_means), z(v_quats), z(v_log_scales), z(v_logits), z(v_sh))


# ----------------------------------------------------------------------------------------------
# bin
# ----------------------------------------------------------------------------------------------
def bin(proj: Projected, width: int, height: int) -> Bins:  # noqa: A001 (stage name)
    """Per-tile depth-ordered lists (exact integer semantics of base.py); a projection that cannot be binned
    (base.bin_problem: its shapes, its visible rows' tile rects) raises ValueError."""
    problem = bin_problem(proj, width, height)
    if problem:
        raise ValueError(f"bin: {problem}")
    tiles_x, tiles_y = tile_grid(width, height)
    n_tiles = tiles_x * tiles_y
    radii = np.asarray(proj.radii)
    vis = np.nonzero(radii > 0)[0]
    depths = np.asarray(proj.depths, np.float64)
    order = np.lexsort((vis, depths[vis]))  # primary depth, then gid: a stable sort by depth
    gid_from_rank = vis[order].astype(np.int64)
    rect = np.asarray(proj.tile_rect, np.int64)[gid_from_rank]  # [V, 4]
    w = rect[:, 2] - rect[:, 0]
    counts = w * (rect[:, 3] - rect[:, 1])
    offset_from_rank = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
    k = int(offset_from_rank[-1])
    # emit order: ranks in order, each Gaussian's tiles row-major (ty outer, tx inner)
    rank_of_emit = np.repeat(np.arange(len(gid_from_rank)), counts)
    local = np.arange(k) - offset_from_rank[rank_of_emit]
    wr = w[rank_of_emit]
    tile_y = rect[rank_of_emit, 1] + local // np.maximum(wr, 1)
    tile_x = rect[rank_of_emit, 0] + local % np.maximum(wr, 1)
    tile_of_emit = tile_y * tiles_x + tile_x
    # emit order is already (depth, gid) within each tile, so a stable sort by tile suffices
    emit_from_isect = np.argsort(tile_of_emit, kind="stable")
    gid_from_isect = gid_from_rank[rank_of_emit][emit_from_isect]
    tiles_sorted = tile_of_emit[emit_from_isect]
    t = np.arange(n_tiles)
    tile_ranges = np.stack([np.searchsorted(tiles_sorted, t, "left"),
                            np.searchsorted(tiles_sorted, t, "right")], axis=1)
    i32 = lambda a: np.ascontiguousarray(a, dtype=np.int32)  # noqa: E731
    return Bins(gid_from_rank=i32(gid_from_rank), offset_from_rank=i32(offset_from_rank),
                gid_from_isect=i32(gid_from_isect), emit_from_isect=i32(emit_from_isect),
                tile_ranges=i32(tile_ranges.reshape(n_tiles, 2)))


# ----------------------------------------------------------------------------------------------
# rasterize_fwd / rasterize_bwd (vectorised over the pixels of one tile and its list)
# ----------------------------------------------------------------------------------------------
def _tile_pixels(tile: int, tiles_x: int, width: int, height: int):
    """Pixel coordinates (i [P], j [P]) of the in-image pixels of `tile`, row-major."""
    tx, ty = tile % tiles_x, tile // tiles_x
    i = np.arange(tx * TILE_SIZE, min((tx + 1) * TILE_SIZE, width))
    j = np.arange(ty * TILE_SIZE, min((ty + 1) * TILE_SIZE, height))
    jj, ii = np.meshgrid(j, i, indexing="ij")
    return ii.ravel(), jj.ravel()


def _tile_blend(proj: Projected, gids: np.ndarray, ii: np.ndarray, jj: np.ndarray, alpha_min: float):
    """The per-pixel front-to-back loop of the spec, for P pixels and the K Gaussians of one tile,
    as [P, K] arrays. `cumprod` multiplies in list order, so T is bit-identical to the loop."""
    m = proj.means2d[gids]  # [K, 2]
    A, B, C = proj.conics[gids, 0], proj.conics[gids, 1], proj.conics[gids, 2]
    o = proj.opacities[gids]
    dx = m[None, :, 0] - (ii[:, None] + 0.5)  # [P, K]
    dy = m[None, :, 1] - (jj[:, None] + 0.5)
    with np.errstate(over="ignore", invalid="ignore"):
        power = -0.5 * (A * dx * dx + C * dy * dy) - B * dx * dy
        g = np.exp(power)
        raw = o * g
    alpha = np.minimum(ALPHA_MAX, raw)
    valid = (power <= 0.0) & (alpha >= alpha_min)
    a = np.where(valid, alpha, 0.0)
    incl = np.cumprod(1.0 - a, axis=1)  # T after each entry, ignoring the stop
    stop = valid & (incl < T_MIN)
    kk = np.arange(len(gids))
    has_stop = stop.any(axis=1)
    k_stop = np.where(has_stop, np.argmax(stop, axis=1), len(gids))  # first entry not blended
    blended = valid & (kk[None, :] < k_stop[:, None])
    ab = np.where(blended, a, 0.0)
    one_m = 1.0 - ab
    cp = np.cumprod(one_m, axis=1)
    T = np.concatenate([np.ones((len(ii), 1)), cp[:, :-1]], axis=1)  # T before each entry
    final_T = cp[:, -1] if len(gids) else np.ones(len(ii))
    w = ab * T  # α T, zero where not blended
    any_b = blended.any(axis=1)
    last = np.where(any_b, len(gids) - np.argmax(blended[:, ::-1], axis=1), 0) if len(gids) else np.zeros(len(ii), int)
    evaluated = np.minimum(k_stop + 1, len(gids))
    return dict(dx=dx, dy=dy, g=g, raw=raw, ab=ab, blended=blended, T=T, final_T=final_T, w=w,
                last=last, evaluated=evaluated, A=A, B=B, C=C, o=o)


def _check_bins(bins: Bins, proj: Projected, width: int, height: int) -> None:
    problem = bins_problem(bins, proj.means2d.shape[0], width, height)
    if problem:
        raise ValueError(f"rasterize: {problem}")


def rasterize_fwd(proj: Projected, bins: Bins, width: int, height: int,
                  background: Sequence[float] = (0.0, 0.0, 0.0), want_importance: bool = False,
                  alpha_min: float = ALPHA_MIN) -> RasterOut:
    """Blend each pixel's tile list front to back (§3 of the issue). `alpha_min` is a test-only
    knob (the FD tests pass 0); keep the default everywhere else. The stats count of evaluated
    pairs is left on the returned object as `evaluated_pairs`. Bins that cannot be rasterized (base.bins_problem)
    raise ValueError."""
    _check_bins(bins, proj, width, height)
    tiles_x, tiles_y = tile_grid(width, height)
    bg = np.asarray(background, np.float64).reshape(3)
    n = proj.means2d.shape[0]
    rgb = np.zeros((height, width, 3))
    depth = np.zeros((height, width))
    alpha = np.zeros((height, width))
    final_T = np.ones((height, width))
    last = np.zeros((height, width), np.int32)
    importance = np.zeros(n) if want_importance else None
    evaluated = 0
    for tile in range(tiles_x * tiles_y):
        s, e = bins.tile_ranges[tile]
        ii, jj = _tile_pixels(tile, tiles_x, width, height)
        gids = np.asarray(bins.gid_from_isect[s:e], np.int64)
        if len(gids) == 0:
            rgb[jj, ii] = bg
            continue
        r = _tile_blend(proj, gids, ii, jj, alpha_min)
        w = r["w"]
        rgb[jj, ii] = w @ proj.colors[gids] + r["final_T"][:, None] * bg
        depth[jj, ii] = w @ proj.depths[gids]
        alpha[jj, ii] = w.sum(axis=1)
        final_T[jj, ii] = r["final_T"]
        last[jj, ii] = r["last"]
        evaluated += int(r["evaluated"].sum())
        if importance is not None:
            np.add.at(importance, gids, w.sum(axis=0))
    out = RasterOut(rgb=rgb, depth=depth, alpha=alpha, final_T=final_T, last=last, importance=importance)
    out.evaluated_pairs = evaluated  # type: ignore[attr-defined]
    return out


def rasterize_bwd(proj: Projected, bins: Bins, raster_out: RasterOut, v_rgb, v_depth, v_alpha,
                  width: int, height: int, background: Sequence[float] = (0.0, 0.0, 0.0),
                  alpha_min: float = ALPHA_MIN) -> RasterGrads:
    """VJP of `rasterize_fwd` w.r.t. the projected quantities (bins held fixed), reduced per gid.

    For pixel p with cotangents (vC, vD, vA), let g_k = vC·c_k + vD z_k + vA and w_k = α_k T_k.
    L_p = Σ_k w_k g_k + T_final (vC·bg), so for a blended entry k
        dL/dα_k = T_k g_k - (Σ_{j>k} w_j g_j + T_final vC·bg) / (1 - α_k)
    (suffix sums; T recomputed front to back, never by division). Entries that were skipped or not
    reached get nothing; dα/d(opacity, power) is zero where opacity*exp(power) > ALPHA_MAX.
    `raster_out` is accepted for the stage signature; the forward is recomputed.
    """
    _check_bins(bins, proj, width, height)
    tiles_x, tiles_y = tile_grid(width, height)
    bg = np.asarray(background, np.float64).reshape(3)
    n = proj.means2d.shape[0]
    v_rgb = np.zeros((height, width, 3)) if v_rgb is None else np.asarray(v_rgb, np.float64)
    v_depth = np.zeros((height, width)) if v_depth is None else np.asarray(v_depth, np.float64)
    v_alpha = np.zeros((height, width)) if v_alpha is None else np.asarray(v_alpha, np.float64)
    v_means2d, v_conics = np.zeros((n, 2)), np.zeros((n, 3))
    v_colors, v_opac, v_depths = np.zeros((n, 3)), np.zeros(n), np.zeros(n)
    for tile in range(tiles_x * tiles_y):
        s, e = bins.tile_ranges[tile]
        if e <= s:
            continue
        ii, jj = _tile_pixels(tile, tiles_x, width, height)
        gids = np.asarray(bins.gid_from_isect[s:e], np.int64)
        r = _tile_blend(proj, gids, ii, jj, alpha_min)
        vC, vD, vA = v_rgb[jj, ii], v_depth[jj, ii], v_alpha[jj, ii]  # [P, 3], [P], [P]
        c, z = proj.colors[gids], proj.depths[gids]
        w, T, ab, bl = r["w"], r["T"], r["ab"], r["blended"]
        gk = vC @ c.T + vD[:, None] * z[None, :] + vA[:, None]  # [P, K]
        wg = w * gk
        suffix = np.cumsum(wg[:, ::-1], axis=1)[:, ::-1] - wg  # Σ_{j>k}
        bgterm = r["final_T"] * (vC @ bg)
        v_a = np.where(bl, T * gk - (suffix + bgterm[:, None]) / (1.0 - ab), 0.0)
        free = bl & (r["raw"] <= ALPHA_MAX)  # no gradient through the 0.99 clamp
        v_power = np.where(free, v_a * ab, 0.0)
        v_o = np.where(free, v_a * r["g"], 0.0)
        dx, dy, A, B, C = r["dx"], r["dy"], r["A"], r["B"], r["C"]
        vu = (v_power * -(A * dx + B * dy)).sum(0)
        vv = (v_power * -(C * dy + B * dx)).sum(0)
        vA_ = (v_power * (-0.5 * dx * dx)).sum(0)
        vB_ = (v_power * (-dx * dy)).sum(0)
        vC_ = (v_power * (-0.5 * dy * dy)).sum(0)
        np.add.at(v_means2d, gids, np.stack([vu, vv], 1))
        np.add.at(v_conics, gids, np.stack([vA_, vB_, vC_], 1))
        np.add.at(v_colors, gids, w.T @ vC)
        np.add.at(v_opac, gids, v_o.sum(0))
        np.add.at(v_depths, gids, w.T @ vD)
    return RasterGrads(v_means2d=v_means2d, v_conics=v_conics, v_colors=v_colors,
                       v_opacities=v_opac, v_depths=v_depths)


# ----------------------------------------------------------------------------------------------
# Whole render in float64
# ----------------------------------------------------------------------------------------------
def render64(g, cam: Camera, background=(0.0, 0.0, 0.0), near: float = 0.01, opacity_override=None,
             want_importance: bool = False, alpha_min: float = ALPHA_MIN, drop: Drop | None = None):
    """float64 forward (drop: DropGaussian's mask, `project_fwd`). Returns (Projected, Bins,
    RasterOut, stats dict)."""
    proj = project_fwd(g, cam, near, opacity_override, drop, alpha_min)
    bins = bin(proj, cam.width, cam.height)
    out = rasterize_fwd(proj, bins, cam.width, cam.height, background, want_importance, alpha_min)
    stats = dict(visible=int(np.count_nonzero(proj.radii > 0)),
                 intersections=int(len(bins.gid_from_isect)),
                 evaluated_pairs=int(out.evaluated_pairs))
    return proj, bins, out, stats


def render_vjp64(g, cam: Camera, v_rgb, v_depth=None, v_alpha=None, background=(0.0, 0.0, 0.0),
                 near: float = 0.01, opacity_override=None, alpha_min: float = ALPHA_MIN,
                 drop: Drop | None = None) -> Params64:
    """float64 VJP of `render64` w.r.t. the raw fields (the mask `drop` held fixed): Params64 of
    gradients."""
    return _vjp64(g, cam, v_rgb, v_depth, v_alpha, background, near, opacity_override, alpha_min, drop)[0]


def _vjp64(g, cam, v_rgb, v_depth, v_alpha, background, near, opacity_override, alpha_min=ALPHA_MIN,
           drop: Drop | None = None):
    """(Params64 gradients, Projected, RasterGrads) of one render."""
    proj, bins, out, _ = render64(g, cam, background, near, opacity_override, False, alpha_min, drop)
    grads = rasterize_bwd(proj, bins, out, v_rgb, v_depth, v_alpha, cam.width, cam.height,
                          background, alpha_min)
    return project_bwd(g, cam, proj, grads, near, opacity_override, drop), proj, grads


class ReferenceBackend:
    """device="reference": float64 numpy, float32 results at the API edge. Trains with the host
    trainer only (`engines`); its host losses are reference_loss's."""

    name = "reference"
    engines = ("host",)
    last_screen = None  # Backend.last_screen, set by render_vjp

    project_fwd = staticmethod(project_fwd)
    bin = staticmethod(bin)
    rasterize_fwd = staticmethod(rasterize_fwd)
    rasterize_bwd = staticmethod(rasterize_bwd)
    project_bwd = staticmethod(project_bwd)
    photometric_loss = staticmethod(_photometric_loss)
    depth_loss = staticmethod(_depth_loss)

    @staticmethod
    def view_warp(virt, depth, gt, fx: float, baseline: float, weight: float, smooth_weight: float):
        """Backend.view_warp: reference_view_warp's float64 twin, float32 cotangents."""
        from .reference_view_warp import view_warp_fwd_bwd, view_warp_state

        loss, v_virt, v_depth = view_warp_fwd_bwd(virt, depth, gt, fx, baseline, weight, smooth_weight)
        valid = float(view_warp_state(virt, depth, gt, fx, baseline).valid.mean())
        return ({"loss": float(loss), "valid_fraction": valid}, v_virt.astype(np.float32),
                v_depth.astype(np.float32))

    def trainer(self, images, engine: str = "auto", adam: str = "auto", profile: dict | None = None):
        """Backend.trainer: the HostTrainer (reings/backends/host_trainer.py); "device" is a
        ValueError (no device here). `adam` is ignored: the host trainer's Adam is numpy."""
        from .host_trainer import HostTrainer

        select_engine(self, engine)
        return HostTrainer(self, images, profile=profile)

    def render(self, gaussians: Gaussians, camera: Camera, background: Sequence[float] = (0, 0, 0),
               near: float = 0.01, opacity_override: float | None = None,
               want_importance: bool = False, drop: Drop | None = None) -> RenderOutput:
        _, _, out, stats = render64(gaussians, camera, background, near, opacity_override, want_importance,
                                    drop=drop)
        f32 = lambda a: np.ascontiguousarray(a, dtype=np.float32)  # noqa: E731
        return RenderOutput(rgb=f32(out.rgb), depth=f32(out.depth), alpha=f32(out.alpha),
                            final_T=f32(out.final_T),
                            importance=None if out.importance is None else f32(out.importance),
                            stats=stats)

    def render_frames(self, gaussians: Gaussians, cameras, background=(0, 0, 0), near: float = 0.01,
                      depth: bool = False):
        for cam in cameras:
            out = self.render(gaussians, cam, background, near)
            yield out.rgb, (out.depth if depth else None)

    def render_vjp(self, gaussians: Gaussians, camera: Camera, v_rgb: np.ndarray,
                   v_depth: np.ndarray | None = None, v_alpha: np.ndarray | None = None,
                   background: Sequence[float] = (0, 0, 0), near: float = 0.01,
                   opacity_override: float | None = None,
                   grad_fields: Sequence[str] | None = None, drop: Drop | None = None) -> Gaussians:
        gr, proj, rg = _vjp64(gaussians, camera, v_rgb, v_depth, v_alpha, background, near, opacity_override,
                              drop=drop)
        # screen-space side channel for the densification statistics (Backend.last_screen)
        self.last_screen = (rg.v_means2d.astype(np.float32), np.asarray(proj.radii)) if grad_fields is None else None
        keep = FIELDS if grad_fields is None else tuple(grad_fields)
        with np.errstate(over="ignore"):
            return Gaussians(*(getattr(gr, f).astype(np.float32) if f in keep
                               else np.zeros_like(getattr(gr, f), dtype=np.float32) for f in FIELDS))

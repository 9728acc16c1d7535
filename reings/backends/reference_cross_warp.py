"""Float64 twin of the cross-view photometric term (`cross_warp`; kernels/cross_warp.cl;
docs/method.md §12), the float32 mirror of the kernel that the host trainer runs (cross_warp_f32: its gradient and its
row sums, which the host trainer takes apart: the sums only when read), and the kernel's
camera arguments.

The term, for the training view i of the iteration and a partner training view j != i:

    L = w / (3 H W) * sum over valid pixels p of view i, channels c of |I_j(p') - I_i(p)|_c

z_p = D_p / a_p the depth along the optical axis (D the rendered depth sum z alpha T, a the rendered
alpha, held constant), X = z_p K_i^-1 (x + 0.5, y + 0.5, 1) in camera i, X_j = R_j R_i^T (X - t_i) + t_j
in camera j, p' = (K_j X_j / z_j) - 0.5 in pixel indices of view j, I_j view j's training image
sampled bilinearly at p', I_i view i's training image at p. Valid: a_p >= alpha_min, z_p finite and
> near, z_j > near, 0 <= p'_x <= W_j - 1 and 0 <= p'_y <= H_j - 1 (the far border uses the last cell,
fraction 1). The gradient reaches D only (the images are constants):

    dL/dD_p = w / (3 H W) / a_p * sum_c sign(r_c) (dI/du du/dz + dI/dv dv/dz)

with the bilinear cell's slopes (one-sided at integer positions: the cell to the right / below)
and du/dz = f_x (dX_j,x z_j - X_j,x dz_j) / z_j^2 along the ray (dX_j = R_j R_i^T K_i^-1 q). The
normaliser is the constant 3 H W (as the view_warp term's L1, docs/binocular.md): the loss is then one
fixed function of D, its gradient needs no reduction before it, and a view pair that overlaps less
pulls less.

The occlusion test (`occlusion` = tol > 0; off at 0): with D_j, a_j view j's rendered depth and alpha
(a render of the partner, held constant), a pixel otherwise valid is occluded, and left out, when
a_j >= alpha_min and z_j > (D_j / a_j) (1 + tol) at the nearest pixel of p',
(floor(p'_x + 0.5), floor(p'_y + 0.5)) clamped to (W_j - 1, H_j - 1); where a_j < alpha_min there is no
test. The gradient of the pixels left valid is unchanged (the test is a step: no derivative).

Blur levels (LossConfig.cross_warp_blur; docs/method.md §12): the same term on copies of both
training images blurred by `blur_image` (a separable Gaussian of standard deviation sigma pixels,
radius ceil(3 sigma), weights summing to 1, reflect-101 borders, float64 rounded once to float32);
the kernel, the mirror and the twin take them as they take the sharp images.
"""
from __future__ import annotations

import numpy as np

CROSS_WARP_ALPHA_MIN = 0.5  # pixels of lower rendered alpha are left out (their z = D / a is ill-defined)

_F32 = np.float32


def blur_kernel(sigma: float) -> np.ndarray:
    """The float64 weights of `blur_image`'s 1-D Gaussian: exp(-x^2 / (2 sigma^2)) for the
    integers x in [-r, r], r = ceil(3 sigma), divided by their sum (so they sum to 1)."""
    r = int(np.ceil(3.0 * float(sigma)))
    x = np.arange(-r, r + 1, dtype=np.float64)
    with np.errstate(over="ignore", divide="ignore"):
        k = np.exp(-0.5 * (x / float(sigma)) ** 2)
    return k / np.sum(k)


def _reflect101_index(n: int, r: int) -> np.ndarray:
    """Indices of a length-n axis padded by r on each side, mirrored without repeating the edge
    (reflect-101: ... 2 1 | 0 1 2 ... n-1 | n-2 n-3 ...), folded again as often as r needs; a
    length-1 axis repeats its one sample."""
    i = np.arange(-r, n + r)
    if n == 1:
        return np.zeros_like(i)
    p = 2 * (n - 1)
    i = np.mod(i, p)
    return np.where(i >= n, p - i, i)


def blur_image(img, sigma: float):
    """`img` [H,W] or [H,W,C] blurred by a separable Gaussian of standard deviation `sigma`
    pixels (blur_kernel: radius ceil(3 sigma), weights summing to 1) along the rows, then the
    columns, with reflect-101 borders (mirrored without repeating the edge pixel), computed in
    float64 and rounded once to float32. sigma 0 returns `img` itself (the same object,
    untouched). The cross_warp term's blur levels (LossConfig.cross_warp_blur): both trainers
    take these float32 images, so the kernel and the host mirror see the same inputs."""
    sigma = float(sigma)
    if not (sigma >= 0 and np.isfinite(sigma)):
        raise ValueError(f"blur_image: sigma must be a finite number >= 0, got {sigma}")
    if sigma == 0:
        return img
    a = np.asarray(img, np.float64)
    if a.ndim not in (2, 3) or 0 in a.shape[:2]:
        raise ValueError(f"blur_image: expected a non-empty [H,W] or [H,W,C] image, got shape {a.shape}")
    k = blur_kernel(sigma)
    r = (len(k) - 1) // 2
    h, w = a.shape[:2]
    cols = a[:, _reflect101_index(w, r)]  # [H, W + 2r, ...]
    out = np.zeros_like(a)
    for t in range(len(k)):  # along x: fixed order, tap by tap
        out += k[t] * cols[:, t:t + w]
    rows = out[_reflect101_index(h, r)]  # [H + 2r, W, ...]
    out = np.zeros_like(a)
    for t in range(len(k)):  # along y
        out += k[t] * rows[t:t + h]
    return out.astype(np.float32)


def relative_pose(cam_i, cam_j) -> tuple[np.ndarray, np.ndarray]:
    """(R, t), float64, with X_j = R X_i + t: R = R_j R_i^T, t = R_j (C_i - C_j) (exactly 0 when
    the two centres are the same numbers)."""
    ri, rj = cam_i.viewmat[:3, :3], cam_j.viewmat[:3, :3]
    return rj @ ri.T, rj @ (cam_i.center - cam_j.center)


def cross_warp_args(cam_i, cam_j) -> tuple[np.ndarray, np.ndarray]:
    """The kernel's geometry: hm = K_j R K_i^-1 (float32 [9], row-major) and e = K_j t (float32 [3])."""
    r, t = relative_pose(cam_i, cam_j)
    ki_inv = np.array([[1.0 / cam_i.fx, 0.0, -cam_i.cx / cam_i.fx], [0.0, 1.0 / cam_i.fy, -cam_i.cy / cam_i.fy],
                       [0.0, 0.0, 1.0]])
    return (cam_j.K @ r @ ki_inv).astype(_F32).reshape(9), (cam_j.K @ t).astype(_F32)


def cross_warp_fwd_bwd(depth, alpha, image_i, image_j, cam_i, cam_j, weight: float, near: float,
                       alpha_min: float = CROSS_WARP_ALPHA_MIN, occlusion: float = 0.0, depth_j=None, alpha_j=None):
    """The term in float64 from the cameras (module docstring). Returns (L, dL/dD [H,W], valid [H,W]).
    occlusion: the occlusion test's tolerance (0: off), against view j's rendered depth_j, alpha_j
    [H_j,W_j] (needed when on); the occluded pixels are those valid with occlusion 0 and not with it."""
    d = np.asarray(depth, np.float64)
    a = np.asarray(alpha, np.float64)
    ii = np.asarray(image_i, np.float64)
    ij = np.asarray(image_j, np.float64)
    h, w = d.shape
    hj, wj = ij.shape[:2]
    if a.shape != d.shape or ii.shape != (h, w, 3) or ij.shape != (hj, wj, 3):
        raise ValueError(f"cross_warp: depth {d.shape}, alpha {a.shape}, image_i {ii.shape}, image_j {ij.shape}")
    if not alpha_min > 0:
        raise ValueError(f"cross_warp: alpha_min must be > 0, got {alpha_min}")
    ys, xs = np.mgrid[0:h, 0:w].astype(np.float64)
    ray = np.stack([(xs + 0.5 - cam_i.cx) / cam_i.fx, (ys + 0.5 - cam_i.cy) / cam_i.fy, np.ones_like(xs)], -1)
    ok = a >= alpha_min
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        z = np.where(ok, d / np.where(ok, a, 1.0), np.nan)
        ok &= np.isfinite(z) & (z > near)
        z = np.where(ok, z, 1.0)
        ri, ti = cam_i.viewmat[:3, :3], cam_i.viewmat[:3, 3]
        rj, tj = cam_j.viewmat[:3, :3], cam_j.viewmat[:3, 3]
        xw = (z[..., None] * ray - ti) @ ri  # R_i^T (X - t_i), row vectors
        xj = xw @ rj.T + tj
        dxj = ray @ (rj @ ri.T).T  # dX_j / dz
        zj = xj[..., 2]
        ok &= zj > near
        zs = np.where(ok, zj, 1.0)
        u = cam_j.fx * xj[..., 0] / zs + cam_j.cx - 0.5
        v = cam_j.fy * xj[..., 1] / zs + cam_j.cy - 0.5
        ok &= (u >= 0) & (u <= wj - 1) & (v >= 0) & (v <= hj - 1) & (wj >= 2) & (hj >= 2)
        if occlusion > 0:
            ok &= ~_occluded64(ok, u, v, zj, depth_j, alpha_j, (hj, wj), occlusion, alpha_min)
        dudz = cam_j.fx * (dxj[..., 0] * zs - xj[..., 0] * dxj[..., 2]) / zs ** 2
        dvdz = cam_j.fy * (dxj[..., 1] * zs - xj[..., 1] * dxj[..., 2]) / zs ** 2
    u, v = np.where(ok, u, 0.0), np.where(ok, v, 0.0)
    x0 = np.minimum(np.floor(u).astype(np.int64), max(wj - 2, 0))
    y0 = np.minimum(np.floor(v).astype(np.int64), max(hj - 2, 0))
    fu, fv = (u - x0)[..., None], (v - y0)[..., None]
    x1, y1 = np.minimum(x0 + 1, wj - 1), np.minimum(y0 + 1, hj - 1)
    i00, i01, i10, i11 = ij[y0, x0], ij[y0, x1], ij[y1, x0], ij[y1, x1]
    smp = (1 - fu) * (1 - fv) * i00 + fu * (1 - fv) * i01 + (1 - fu) * fv * i10 + fu * fv * i11
    gu = (1 - fv) * (i01 - i00) + fv * (i11 - i10)
    gv = (1 - fu) * (i10 - i00) + fu * (i11 - i01)
    r = smp - ii
    scale = float(weight) / (3.0 * h * w)
    okc = ok[..., None]
    loss = scale * float(np.sum(np.where(okc, np.abs(r), 0.0)))
    s = np.sign(r)
    gz = np.sum(s * (gu * dudz[..., None] + gv * dvdz[..., None]), -1)
    grad = np.where(ok, scale * gz / np.where(ok, a, 1.0), 0.0)
    return loss, grad, ok


def _occluded64(ok, u, v, zj, depth_j, alpha_j, shape_j, tol: float, alpha_min: float):
    """The occlusion test in float64 (module docstring): [H,W] bool, True where `ok` and view j's
    surface at p's nearest pixel (u, v: p' in pixel indices) is nearer than z_j / (1 + tol)."""
    if depth_j is None or alpha_j is None:
        raise ValueError("cross_warp: the occlusion test needs the partner's rendered depth_j and alpha_j")
    dj, aj = np.asarray(depth_j, np.float64), np.asarray(alpha_j, np.float64)
    if dj.shape != shape_j or aj.shape != shape_j:
        raise ValueError(f"cross_warp: depth_j {dj.shape}, alpha_j {aj.shape}, partner image {shape_j}")
    xn = np.minimum(np.floor(np.where(ok, u, 0.0) + 0.5).astype(np.int64), shape_j[1] - 1)
    yn = np.minimum(np.floor(np.where(ok, v, 0.0) + 0.5).astype(np.int64), shape_j[0] - 1)
    a = aj[yn, xn]
    test = a >= alpha_min
    zn = dj[yn, xn] / np.where(test, a, 1.0)
    return ok & test & (zj > zn * (1.0 + tol))


def cross_warp_f32(depth, alpha, image_i, image_j, hm, e, near: float, alpha_min: float, scale,
                   tol: float = 0.0, depth_j=None, alpha_j=None):
    """kernels/cross_warp.cl's float32 operations in its order, vectorised (the host trainer's
    mirror): (dL/dD [H,W] float32, row sums of |r| [H] float32 (left to right, channels in order),
    valid pixels per row [H] int64, occluded pixels per row [H] int64). hm, e: cross_warp_args;
    scale: float32(w / (3 H W)); tol, depth_j, alpha_j: the occlusion test (tol 0: off)."""
    g, r, ok, occ = cross_warp_grad_f32(depth, alpha, image_i, image_j, hm, e, near, alpha_min, scale,
                                        tol, depth_j, alpha_j)
    return (g, *cross_warp_rows_f32(r, ok, occ))


def cross_warp_rows_f32(r, ok, occ):
    """cross_warp_rows's float32 sums from cross_warp_grad_f32's residuals, valid and occluded
    masks: (row sums of |r| [H] float32, left to right, channels in order; valid pixels per row [H]
    int64; occluded pixels per row [H] int64)."""
    f = _F32
    h, w = ok.shape
    ab = np.where(ok[..., None], np.abs(r), f(0)).astype(f)
    rows = np.zeros(h, f)
    for x in range(w):  # left to right, channels in order, as cross_warp_rows
        for c in range(3):
            rows = rows + ab[:, x, c]
    return rows, ok.sum(1), occ.sum(1)


def cross_warp_grad_f32(depth, alpha, image_i, image_j, hm, e, near: float, alpha_min: float, scale,
                        tol: float = 0.0, depth_j=None, alpha_j=None):
    """cross_warp_grad's float32 operations in its order: (dL/dD [H,W] float32, the residuals
    [H,W,3] float32, valid [H,W] bool, occluded [H,W] bool); the row sums come from
    cross_warp_rows_f32 when read. tol > 0: the occlusion test against view j's rendered depth_j,
    alpha_j [Hj,Wj]."""
    f = _F32
    d = np.asarray(depth, f)
    a = np.asarray(alpha, f)
    ii = np.asarray(image_i, f)
    ij = np.asarray(image_j, f)
    h, w = d.shape
    hj, wj = ij.shape[:2]
    hm, e = np.asarray(hm, f), np.asarray(e, f)
    near, amin, scale = f(near), f(alpha_min), f(scale)
    ys, xs = np.mgrid[0:h, 0:w]
    qx, qy = xs.astype(f) + f(0.5), ys.astype(f) + f(0.5)
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        ok = (a >= amin) & (wj >= 2) & (hj >= 2)
        z = d / a
        ok &= (z > near) & np.isfinite(z)
        wv = f(1) / z
        hx = hm[0] * qx + hm[1] * qy + hm[2]
        hy = hm[3] * qx + hm[4] * qy + hm[5]
        hz = hm[6] * qx + hm[7] * qy + hm[8]
        sx, sy, sz = hx + wv * e[0], hy + wv * e[1], hz + wv * e[2]
        ok &= (z * sz) > near
        u = sx / sz - f(0.5)
        v = sy / sz - f(0.5)
        ok &= (u >= f(0)) & (u <= f(wj - 1)) & (v >= f(0)) & (v <= f(hj - 1))
        u, v = np.where(ok, u, f(0)), np.where(ok, v, f(0))
        occ = np.zeros((h, w), bool)
        if f(tol) > 0:  # the kernel's test, in its float32 operations (tol as the kernel gets it)
            if depth_j is None or alpha_j is None:
                raise ValueError("cross_warp: the occlusion test needs the partner's rendered depth_j and alpha_j")
            dj, aj = np.asarray(depth_j, f), np.asarray(alpha_j, f)
            xn = np.minimum(np.floor(u + f(0.5)).astype(np.int64), wj - 1)
            yn = np.minimum(np.floor(v + f(0.5)).astype(np.int64), hj - 1)
            an = aj[yn, xn]
            occ = ok & (an >= amin) & ((z * sz) > (dj[yn, xn] / an) * (f(1) + f(tol)))
            ok &= ~occ
        x0 = np.minimum(np.floor(u).astype(np.int64), max(wj - 2, 0))
        y0 = np.minimum(np.floor(v).astype(np.int64), max(hj - 2, 0))
        fu, fv = u - x0.astype(f), v - y0.astype(f)
        x1, y1 = np.minimum(x0 + 1, wj - 1), np.minimum(y0 + 1, hj - 1)
        acc_u = np.zeros((h, w), f)
        acc_v = np.zeros((h, w), f)
        r = np.zeros((h, w, 3), f)
        for c in range(3):
            i00, i01 = ij[y0, x0, c], ij[y0, x1, c]
            i10, i11 = ij[y1, x0, c], ij[y1, x1, c]
            dt, db = i01 - i00, i11 - i10
            top, bot = i00 + fu * dt, i10 + fu * db
            rc = (top + fv * (bot - top)) - ii[..., c]
            r[..., c] = rc
            sg = np.where(rc > 0, f(1), np.where(rc < 0, f(-1), f(0))).astype(f)
            acc_u = acc_u + sg * (dt + fv * (db - dt))
            acc_v = acc_v + sg * (bot - top)
        k = wv / sz
        k2 = k * k
        dudz = (sx * e[2] - e[0] * sz) * k2
        dvdz = (sy * e[2] - e[1] * sz) * k2
        gz = acc_u * dudz + acc_v * dvdz
        g = np.where(ok, scale * (gz / a), f(0)).astype(f)
    return g, r, ok, occ

"""Built-in multi-view stereo depth prior (no network): plane sweep + windowed NCC.

Used through `reings.data.depth_prior.get_depth_prior("stereo")`; `stereo_depths` is the pure
function (no cache). It sees only the views it is given (the training views), their cameras and
optionally sparse points built from those same views.

Per reference view r:

1. Depth hypotheses: D fronto-parallel planes z = d in r's camera, uniform in inverse depth
   between `near` and `far` (with `slants`, the same D planes again for each extra orientation
   (yaw, pitch) in degrees: planes turned about r's y and x axes, scored per pixel by the inverse
   depth they give along its ray; each orientation is aggregated on its own and the best
   aggregated score wins). near/far come from the arguments, else from `bounds` (each view's own
   near/far), else from sparse points (1st / 99th
   percentile of their depths in r, widened by 0.8 / 1.25), else from the camera baselines: the
   nearest plane gives `max_disparity_frac` x width of disparity towards the farthest other view,
   the farthest plane `min_disparity_px` towards the nearest other view. D is chosen so that one
   step is about one pixel of disparity (clipped to [48, 256]) unless `num_depths` is given.
2. For each other view s and plane: the grey image of s is warped into r by the plane homography
   H = K_s (R + t e3^T / d) K_r^-1 (cv2.warpPerspective, bilinear) and compared with r by
   zero-mean NCC over a `window` x `window` box (cv2.blur). Pixels whose warped position leaves s
   or falls behind it get NCC = -1 for that view.
3. Aggregation over the other views: the mean of the best ceil(S/2) NCC values (occlusion-robust
   for S >= 3; the max for S = 2, the value itself for S = 1).
4. Semi-global aggregation (`sgm=True`, Hirschmueller's SGM on the cost 1 - NCC along the 4
   image-axis directions, penalties `sgm_p1` for a one-plane step and `sgm_p2` for larger jumps,
   P2 lowered across intensity edges): repeated textures and weak texture get the depth their
   neighbours support. Then winner-take-all over planes and a parabola through the neighbouring
   aggregated costs for a sub-plane inverse depth.
   Wide baselines need far stronger penalties (DTU's recipe: 0.2 / 9.6 with each view's
   bounds, `reings.pipeline.STEREO_BY_FAMILY`; docs/results.md §15).
5. Confidence in [0, 1] = clip(NCC, 0, 1) x (fraction of the other views whose own depth map
   agrees within `consistency` relative depth after reprojection: the multi-view left-right
   check), set to 0 where r has no texture (window std < `min_texture`) or the peak NCC is below
   `ncc_min`.
6. Pixels with confidence below `conf_min` are filled from the confident ones: push-pull
   (pyramid normalised convolution) on inverse depth, then a guided filter (grey image as guide)
   on the filled pixels only, so fills follow image edges.

Pixel conventions are those of `reings.Camera` (pixel (i, j) centred at (i + 0.5, j + 0.5)).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["StereoResult", "stereo_depths", "depth_range"]


@dataclass
class StereoResult:
    depth: np.ndarray  # (H, W) float32, filled, z-depth in the scene's units
    confidence: np.ndarray  # (H, W) float32 in [0, 1]
    raw_depth: np.ndarray  # (H, W) float32 before filling (winner-take-all + sub-plane)
    ncc: np.ndarray  # (H, W) float32 aggregated NCC at the winner
    near: float
    far: float
    num_depths: int


def _cv2():
    try:
        import cv2
    except ImportError as e:  # pragma: no cover
        raise ImportError("the stereo depth prior needs OpenCV (pip install opencv-python-headless)") from e
    return cv2


def _gray(img) -> np.ndarray:
    a = np.asarray(img, dtype=np.float32)
    return np.ascontiguousarray(0.299 * a[..., 0] + 0.587 * a[..., 1] + 0.114 * a[..., 2], dtype=np.float32)


def _kcv(K) -> np.ndarray:
    """K for OpenCV pixel coordinates (pixel centres at integers)."""
    K = np.array(K, dtype=np.float64)
    K[0, 2] -= 0.5
    K[1, 2] -= 0.5
    return K


def _convergence_depth(cameras, r: int, min_angle_deg: float = 3.0):
    """Smallest depth (along r's optical axis) where r's axis passes closest to another view's
    axis, over the views whose axes converge at > min_angle_deg in front of both; else None."""
    cr = cameras[r]
    o1, a1 = cr.center, cr.viewmat[2, :3] / np.linalg.norm(cr.viewmat[2, :3])
    best = None
    for s, cs in enumerate(cameras):
        if s == r:
            continue
        o2, a2 = cs.center, cs.viewmat[2, :3] / np.linalg.norm(cs.viewmat[2, :3])
        c = float(a1 @ a2)
        if c > math.cos(math.radians(min_angle_deg)):
            continue
        w = o1 - o2
        den = 1.0 - c * c
        t = (c * (a2 @ w) - (a1 @ w)) / den
        u = ((a2 @ w) - c * (a1 @ w)) / den
        if t > 0 and u > 0:
            best = t if best is None else min(best, t)
    return best


def depth_range(cameras, r: int, points=None, near=None, far=None, max_disparity_frac=0.25, min_disparity_px=0.5,
                bounds=None):
    """(near, far) for reference view r (see the module docstring); `bounds`: (n, 2) each view's own
    near/far, used before the points and the baselines."""
    cam = cameras[r]
    if near is not None and far is not None:
        return float(near), float(far)
    pn = pf = None
    if bounds is not None:
        pn, pf = float(bounds[r][0]), float(bounds[r][1])
    elif points is not None and len(points) >= 8:
        P = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        z = P @ cam.viewmat[:3, :3].T[:, 2] + cam.viewmat[2, 3]
        z = z[np.isfinite(z) & (z > 0)]
        if z.size >= 8:
            pn = 0.8 * float(np.percentile(z, 1))
            pf = 1.25 * float(np.percentile(z, 99))
    if pn is None:
        c = cam.center
        b = np.array([np.linalg.norm(cameras[s].center - c) for s in range(len(cameras)) if s != r])
        b = b[b > 0]
        if b.size == 0:
            raise ValueError("stereo prior: the views share one camera centre, no baseline to triangulate")
        f = cam.fx
        pn = f * float(b.max()) / (max_disparity_frac * cam.width)
        pf = f * float(b.min()) / float(min_disparity_px)
        zc = _convergence_depth(cameras, r)
        if zc is not None:  # converging views (object-centric, wide arc): cover well in front of it
            pn = min(pn, 0.3 * zc)
            pf = max(3.0 * zc, 1.5 * pn)
    n = float(near) if near is not None else pn
    fa = float(far) if far is not None else pf
    if not (0 < n < fa and math.isfinite(fa)):
        raise ValueError(f"stereo prior: bad depth range near={n}, far={fa}")
    return n, fa


def _box(cv2, x, k):
    return cv2.blur(x, (k, k), borderType=cv2.BORDER_REFLECT)


def _push_pull(val: np.ndarray, w: np.ndarray, cv2) -> np.ndarray:
    """Fill where w == 0 by pyramid normalised convolution (weights w >= 0)."""
    levels = []
    v, ww = (val * w).astype(np.float32), w.astype(np.float32)
    while min(v.shape) > 2:
        levels.append((v, ww))
        v = cv2.pyrDown(v)
        ww = cv2.pyrDown(ww)
    cur = np.where(ww > 1e-8, v / np.maximum(ww, 1e-8), 0.0).astype(np.float32)
    if not np.any(ww > 1e-8):
        cur[:] = float((val * w).sum() / max(w.sum(), 1e-12))
    for v, ww in reversed(levels):
        up = cv2.resize(cur, (v.shape[1], v.shape[0]), interpolation=cv2.INTER_LINEAR)
        a = np.clip(ww, 0.0, 1.0)
        est = np.where(ww > 1e-8, v / np.maximum(ww, 1e-8), up)
        cur = (a * est + (1 - a) * up).astype(np.float32)
    return cur


def _guided(cv2, I, p, r, eps):
    k = 2 * r + 1
    mI, mp = _box(cv2, I, k), _box(cv2, p, k)
    cIp = _box(cv2, I * p, k) - mI * mp
    vI = _box(cv2, I * I, k) - mI * mI
    a = cIp / (vI + eps)
    b = mp - a * mI
    return _box(cv2, a, k) * I + _box(cv2, b, k)


def _plane_normal(yaw_deg: float, pitch_deg: float) -> np.ndarray:
    """Unit normal, in the reference camera's frame (x right, y down, z forward), of a plane
    turned by `yaw_deg` about the camera's y axis and `pitch_deg` about its x axis from the
    fronto-parallel plane (normal (0, 0, 1))."""
    n = np.array([math.tan(math.radians(yaw_deg)), math.tan(math.radians(pitch_deg)), 1.0])
    return n / np.linalg.norm(n)


def _sweep(cv2, r, grays, cameras, invd, window, min_texture, normal=None):
    """Aggregated NCC volume (D, H, W) for reference r, and the per-pixel factor rho (H, W).

    Plane k is {X : n . X = n_z / invd[k]} in r's camera frame (n = `normal`, default (0, 0, 1):
    fronto-parallel, z = 1 / invd[k]); invd[k] is the plane's inverse depth on r's principal ray
    and the inverse depth at pixel p is invd[k] * rho(p), rho = (n . K^-1 p) / n_z. A pixel whose
    inverse depth on the plane leaves [invd[0], invd[-1]] (or whose ray misses the plane) scores
    NCC = -1 there."""
    H, W = grays[r].shape
    g = grays[r]
    mu_r = _box(cv2, g, window)
    var_r = np.maximum(_box(cv2, g * g, window) - mu_r * mu_r, 0.0)
    std_r = np.sqrt(var_r)
    Kr_inv = np.linalg.inv(_kcv(cameras[r].K))
    Vr_inv = np.linalg.inv(cameras[r].viewmat)
    xs, ys = np.meshgrid(np.arange(W, dtype=np.float64), np.arange(H, dtype=np.float64))
    rays = np.stack([xs, ys, np.ones_like(xs)], -1).reshape(-1, 3) @ Kr_inv.T  # z = 1 rays
    n = np.array([0.0, 0.0, 1.0]) if normal is None else np.asarray(normal, dtype=np.float64)
    rho = rays @ n / n[2]  # (HW,)
    lo, hi = float(invd[0]) * (1 - 1e-9), float(invd[-1]) * (1 + 1e-9)
    others = [s for s in range(len(grays)) if s != r]
    S = len(others)
    kbest = max(1, math.ceil(S / 2))
    D = len(invd)
    vol = np.empty((D, H, W), dtype=np.float32)
    ncc_s = np.empty((S, H, W), dtype=np.float32)
    rel = []
    for s in others:
        T = cameras[s].viewmat @ Vr_inv
        Ks = _kcv(cameras[s].K)
        R, t = T[:3, :3], T[:3, 3]
        A = rays @ (Ks @ R).T  # (HW, 3), homogeneous src coords at invd = 0 ... + invd * rho * B
        B = Ks @ t  # (3,)
        rel.append((Ks, R, t, A, B))
    eps = 1e-12
    for k, q in enumerate(invd):
        for si, s in enumerate(others):
            Ks, R, t, A, B = rel[si]
            Hm = Ks @ (R + np.outer(t, n * (q / n[2]))) @ Kr_inv
            w = cv2.warpPerspective(
                grays[s], Hm, (W, H), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP, borderMode=cv2.BORDER_REPLICATE
            )
            mu_w = _box(cv2, w, window)
            var_w = np.maximum(_box(cv2, w * w, window) - mu_w * mu_w, 0.0)
            cov = _box(cv2, g * w, window) - mu_r * mu_w
            ncc = cov / np.sqrt(var_r * var_w + eps)
            # validity: the plane point lies in front of s and inside its image
            qp = q * rho  # inverse depth of the plane along each pixel's ray
            hz = A[:, 2] + qp * B[2]
            hx = A[:, 0] + qp * B[0]
            hy = A[:, 1] + qp * B[1]
            with np.errstate(divide="ignore", invalid="ignore"):
                u = hx / hz
                v = hy / hz
            ok = (hz > 1e-9) & (u >= -0.5) & (u <= cameras[s].width - 0.5) & (v >= -0.5) & (v <= cameras[s].height - 0.5)
            if normal is not None:
                ok &= (qp >= lo) & (qp <= hi)
            ncc = np.where(ok.reshape(H, W), ncc, -1.0)
            ncc_s[si] = np.clip(ncc, -1.0, 1.0)
        if S == 1:
            vol[k] = ncc_s[0]
        elif kbest == 1:
            vol[k] = ncc_s.max(0)
        else:
            part = -np.partition(-ncc_s, kbest - 1, axis=0)[:kbest]
            vol[k] = part.mean(0)
    return vol, std_r, rho.reshape(H, W)


def _sgm(cost: np.ndarray, gray: np.ndarray, P1: float, P2: float) -> np.ndarray:
    """Semi-global aggregation (Hirschmueller 2008) of cost (D, H, W) along the 4 image axes
    directions; P2 is lowered across intensity edges (P2 / (1 + 20 |dI|), at least P1)."""
    D, H, W = cost.shape
    total = np.zeros_like(cost)
    for axis, rev in ((2, False), (2, True), (1, False), (1, True)):
        n = cost.shape[axis]
        order = range(n - 1, -1, -1) if rev else range(n)
        prev = None
        prev_g = None
        for i in order:
            c = cost[:, :, i] if axis == 2 else cost[:, i, :]
            g = gray[:, i] if axis == 2 else gray[i, :]
            if prev is None:
                cur = c.copy()
            else:
                m = prev.min(axis=0)
                p2 = np.maximum(P2 / (1.0 + 20.0 * np.abs(g - prev_g)), P1).astype(np.float32)
                best = np.minimum(prev, (m + p2)[None])
                best[1:] = np.minimum(best[1:], prev[:-1] + P1)
                best[:-1] = np.minimum(best[:-1], prev[1:] + P1)
                cur = c + best - m[None]
            if axis == 2:
                total[:, :, i] += cur
            else:
                total[:, i, :] += cur
            prev, prev_g = cur, g
    return total


def _wta(vol: np.ndarray, invd: np.ndarray):
    D = vol.shape[0]
    best = np.argmax(vol, axis=0)
    c0 = np.take_along_axis(vol, best[None], 0)[0]
    km = np.clip(best - 1, 0, D - 1)
    kp = np.clip(best + 1, 0, D - 1)
    cm = np.take_along_axis(vol, km[None], 0)[0]
    cp = np.take_along_axis(vol, kp[None], 0)[0]
    den = cm - 2 * c0 + cp
    with np.errstate(divide="ignore", invalid="ignore"):
        off = np.where((den < -1e-9) & (best > 0) & (best < D - 1), 0.5 * (cm - cp) / den, 0.0)
    off = np.clip(off, -0.5, 0.5)
    step = (invd[-1] - invd[0]) / max(D - 1, 1)
    q = invd[best] + off * step
    return q.astype(np.float64), c0


def _consistency(depths, cameras, tau):
    """For each view: fraction of other views whose depth agrees within tau (relative)."""
    n = len(depths)
    out = []
    for r in range(n):
        cam = cameras[r]
        H, W = depths[r].shape
        Kr_inv = np.linalg.inv(cam.K)
        xs, ys = np.meshgrid(np.arange(W) + 0.5, np.arange(H) + 0.5)
        pts = np.stack([xs, ys, np.ones_like(xs)], -1).reshape(-1, 3) @ Kr_inv.T * depths[r].reshape(-1, 1)
        Xw = (pts - cam.viewmat[:3, 3]) @ cam.viewmat[:3, :3]  # R^T (x - t)
        agree = np.zeros(H * W, dtype=np.float32)
        for s in range(n):
            if s == r:
                continue
            cs = cameras[s]
            Xs = Xw @ cs.viewmat[:3, :3].T + cs.viewmat[:3, 3]
            z = Xs[:, 2]
            with np.errstate(divide="ignore", invalid="ignore"):
                u = cs.K[0, 0] * Xs[:, 0] / z + cs.K[0, 2]
                v = cs.K[1, 1] * Xs[:, 1] / z + cs.K[1, 2]
            iu = np.floor(np.nan_to_num(u, nan=-1.0)).astype(np.int64)
            iv = np.floor(np.nan_to_num(v, nan=-1.0)).astype(np.int64)
            ok = (z > 0) & (iu >= 0) & (iu < cs.width) & (iv >= 0) & (iv < cs.height)
            ds = np.zeros_like(z)
            ds[ok] = depths[s][iv[ok], iu[ok]]
            good = ok & (np.abs(ds - z) <= tau * z)
            agree += good
        out.append((agree / max(n - 1, 1)).reshape(H, W))
    return out


def stereo_depths(
    images,
    cameras,
    points=None,
    *,
    near=None,
    far=None,
    num_depths=None,
    window: int = 9,
    max_disparity_frac: float = 0.25,
    min_disparity_px: float = 0.5,
    ncc_min: float = 0.5,
    min_texture: float = 0.004,
    consistency: float = 0.03,
    conf_min: float = 0.3,
    fill: bool = True,
    sgm: bool = True,
    sgm_p1: float = 0.03,
    sgm_p2: float = 0.6,
    slants: tuple = (),
    bounds=None,
    progress=None,
) -> list[StereoResult]:
    """Plane-sweep stereo depth for every view in `images` against the others (2 to ~8 views).

    images: list of (H, W, 3) float in [0, 1]; cameras: list of reings.Camera; points: optional
    (P, 3) sparse points *from these views only* (for the depth range). Returns one
    `StereoResult` per view.
    """
    cv2 = _cv2()
    n = len(images)
    if n < 2:
        raise ValueError(f"stereo prior: needs at least 2 posed views, got {n}")
    if len(cameras) != n:
        raise ValueError(f"stereo prior: {n} images but {len(cameras)} cameras")
    if bounds is not None:
        bounds = np.asarray(bounds, dtype=np.float64)
        if bounds.shape != (n, 2) or not np.all(np.isfinite(bounds)) or np.any(bounds[:, 0] <= 0) \
                or np.any(bounds[:, 1] <= bounds[:, 0]):
            raise ValueError(f"stereo prior: bounds must be ({n}, 2) finite with 0 < near < far, got {bounds.tolist()}")
    if window < 3 or window % 2 == 0:
        raise ValueError(f"stereo prior: window must be odd and >= 3, got {window}")
    grays = []
    for i, (im, cam) in enumerate(zip(images, cameras)):
        a = np.asarray(im)
        if a.ndim != 3 or a.shape[2] != 3 or a.shape[:2] != (cam.height, cam.width):
            raise ValueError(f"stereo prior: image {i} has shape {a.shape}, camera is {cam.width}x{cam.height}")
        if not np.all(np.isfinite(a)):
            raise ValueError(f"stereo prior: image {i} has non-finite values")
        grays.append(_gray(a))
    raw, nccs, ranges, stds = [], [], [], []
    for r in range(n):
        nr, fr = depth_range(cameras, r, points, near, far, max_disparity_frac, min_disparity_px, bounds)
        if num_depths is None:
            c = cameras[r].center
            bmax = max(np.linalg.norm(cameras[s].center - c) for s in range(n) if s != r)
            D = int(np.clip(math.ceil((1.0 / nr - 1.0 / fr) * cameras[r].fx * bmax), 48, 256))
        else:
            D = int(num_depths)
        invd = np.linspace(1.0 / fr, 1.0 / nr, D)
        best = None  # (score, inverse depth, NCC at the winner) over the plane orientations
        for normal in [None] + [_plane_normal(*a) for a in slants]:
            vol, std_r, rho = _sweep(cv2, r, grays, cameras, invd, window, min_texture, normal)
            if sgm:
                score = -_sgm(1.0 - vol, grays[r], sgm_p1, sgm_p2)
                q, sc = _wta(score, invd)
                del score
                k = np.clip(np.rint((q - invd[0]) / max(invd[1] - invd[0], 1e-30)), 0, D - 1).astype(np.int64)
                c0 = np.take_along_axis(vol, k[None], 0)[0]
            else:
                q, c0 = _wta(vol, invd)
                sc = c0
            del vol
            qp = q * rho
            if best is None:
                best = (sc, qp, c0)
            else:
                take = sc > best[0]
                best = (np.where(take, sc, best[0]), np.where(take, qp, best[1]), np.where(take, c0, best[2]))
        _, q, c0 = best
        raw.append((1.0 / np.maximum(q, 1e-12)).astype(np.float32))
        nccs.append(c0.astype(np.float32))
        ranges.append((nr, fr, D))
        stds.append(std_r)
        if progress is not None:
            progress(r)
    agree = _consistency(raw, cameras, consistency)
    out = []
    for r in range(n):
        conf = np.clip(nccs[r], 0.0, 1.0) * agree[r]
        conf = np.where((stds[r] >= min_texture) & (nccs[r] >= ncc_min), conf, 0.0).astype(np.float32)
        depth = raw[r]
        if fill:
            good = conf >= conf_min
            if good.any():
                invd_map = (1.0 / raw[r]).astype(np.float32)
                filled = _push_pull(invd_map, good.astype(np.float32), cv2)
                g = grays[r]
                smooth = _guided(cv2, g, filled, 8, 1e-3)
                inv = np.where(good, invd_map, np.maximum(smooth, 1e-12))
                nr, fr, _ = ranges[r]
                inv = np.clip(inv, 1.0 / fr, 1.0 / nr)
                depth = (1.0 / inv).astype(np.float32)
        nr, fr, D = ranges[r]
        out.append(StereoResult(depth.astype(np.float32), conf, raw[r], nccs[r], nr, fr, D))
    return out

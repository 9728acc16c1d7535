/* cross_warp.cl: the cross-view photometric term (docs/method.md §12). The rendered depth of the
 * training view i being trained reprojects each of its pixels into another training view j (the
 * partner, drawn per iteration); the partner's TRAINING IMAGE, sampled bilinearly there, should
 * show the colour that view i's training image has at the pixel:
 *     L = w / (3 H W) * sum over valid p, channels c of |I_j(p'(z_p)) - I_i(p)|_c
 * z_p = D_p / a_p the pixel's depth along the optical axis (D the rendered depth sum z alpha T,
 * a the rendered alpha, held constant as in depth_metric.cl), I_i, I_j fixed images: the gradient
 * reaches D only, through the bilinear sample's position p'.
 *
 * Geometry, with q = (x + 0.5, y + 0.5, 1) the pixel centre of view i (the rasterizer's) and
 * w = 1 / z the inverse depth: the host passes hm = K_j R K_i^-1 (row-major 3x3) and e = K_j t,
 * (R, t) the pose of camera j relative to camera i (X_j = R X_i + t), both rounded to float32 from
 * float64 (reference_cross_warp.cross_warp_args). Then
 *     h = hm q,   s = h + w e,   z_j = z s_z,   p' = (s_x / s_z, s_y / s_z) - 0.5 (pixel indices of j)
 * which is K_j (R z K_i^-1 q + t) / z_j written so that without a translation (e = 0) p' does not
 * depend on z at all, bit for bit. A pixel is valid iff a >= alpha_min, z is finite and > near,
 * z_j > near and 0 <= p'_x <= W_j - 1, 0 <= p'_y <= H_j - 1 (the far border included: the last cell,
 * x0 = W_j - 2, is used with fraction 1). Invalid pixels add nothing and get a zero cotangent.
 *     dL/dD_p = scale / a_p * sum_c sign(r_c) (dI/du du/dz + dI/dv dv/dz),
 *     du/dz = (s_x e_z - e_x s_z) (w / s_z)^2,  dv/dz = (s_y e_z - e_y s_z) (w / s_z)^2
 * with dI/du, dI/dv the bilinear cell's slopes (one-sided at integer positions: the cell to the
 * right / below, the last one at the far border). scale = float32(w / (3 H W)) from the host.
 * Twin: reings.backends.reference_cross_warp.cross_warp_fwd_bwd (float64, written from the
 * cameras); the host trainer mirrors these float32 operations in this order
 * (reference_cross_warp.cross_warp_f32), so on PoCL both trainers give the same bits.
 *
 * Occlusion test (tol > 0; docs/method.md §12): depth_j, alpha_j are view j's rendered depth and
 * alpha ([Hj, Wj], a render of the partner with the current Gaussians, held constant). A pixel
 * otherwise valid is OCCLUDED, and then invalid, when the partner's surface at the nearest pixel
 * of p', (xn, yn) = (floor(p'_x + 0.5), floor(p'_y + 0.5)) at most (Wj - 1, Hj - 1) (ties upward;
 * not the bilinear cell's four: a depth edge blended across pixels is no surface), is nearer than
 * the reprojected point:
 *     alpha_j >= alpha_min  and  z_j > (depth_j / alpha_j) * (1 + tol)
 * (where the partner's alpha is below alpha_min there is no test: the pixel stays valid). With
 * tol == 0 the test is off: depth_j / alpha_j are not read (the host passes any buffers) and every
 * other operation is the same, so the results are those without the test, bit for bit. The
 * gradient of a valid pixel is the one above (the test is a step in z_p: no derivative).
 *
 * cross_warp_grad  global (H * W): v_depth = g, or v_depth += g with accumulate != 0 (the term
 *                  joins the view_warp / depth_metric cotangent in one backward); each pixel
 *                  writes only its own cotangent: no atomics
 * cross_warp_rows  global (H): per row the float32 sum of |r_c| over its valid pixels, left to
 *                  right, channels in order, the count of its valid pixels and that of its
 *                  occluded ones (0 with tol == 0); launched only when the loss is read
 *                  (Trainer.read_cross_warp, logging iterations), on the same frame buffers,
 *                  which hold until the next forward (and the same held partner depth, until
 *                  the next Trainer.hold_depth)
 */
#pragma OPENCL FP_CONTRACT OFF

typedef struct {
    float h00, h01, h02, h10, h11, h12, h20, h21, h22, e0, e1, e2;
} cw_geom;

#define CW_INVALID 0
#define CW_VALID 1
#define CW_OCCLUDED 2  /* valid but for the occlusion test (tol > 0): invalid */

/* The pixel (x, y): CW_VALID with the three residuals r[c] and dL/dz / scale in *gz, else
 * CW_INVALID or CW_OCCLUDED (nothing written). */
static int cw_pixel(const int x, const int y, const int width, const int wj, const int hj,
                    const cw_geom g, const float near, const float alpha_min, const float tol,
                    __global const float *depth, __global const float *alpha,
                    __global const float *img_i, __global const float *img_j,
                    __global const float *depth_j, __global const float *alpha_j,
                    float *r, float *gz)
{
    const int n = y * width + x;
    const float a = alpha[n];
    if (!(a >= alpha_min) || wj < 2 || hj < 2) return CW_INVALID;
    const float z = depth[n] / a;
    if (!(z > near) || !isfinite(z)) return CW_INVALID;
    const float w = 1.0f / z;
    const float qx = (float)x + 0.5f, qy = (float)y + 0.5f;
    const float hx = g.h00 * qx + g.h01 * qy + g.h02;
    const float hy = g.h10 * qx + g.h11 * qy + g.h12;
    const float hz = g.h20 * qx + g.h21 * qy + g.h22;
    const float sx = hx + w * g.e0, sy = hy + w * g.e1, sz = hz + w * g.e2;
    const float zj = z * sz;
    if (!(zj > near)) return CW_INVALID;
    const float u = sx / sz - 0.5f, v = sy / sz - 0.5f;
    if (!(u >= 0.0f && u <= (float)(wj - 1) && v >= 0.0f && v <= (float)(hj - 1))) return CW_INVALID;
    if (tol > 0.0f) {  /* the occlusion test at p's nearest pixel of view j */
        const int xn = min((int)floor(u + 0.5f), wj - 1), yn = min((int)floor(v + 0.5f), hj - 1);
        const int m = yn * wj + xn;
        const float aj = alpha_j[m];
        if (aj >= alpha_min && zj > (depth_j[m] / aj) * (1.0f + tol)) return CW_OCCLUDED;
    }
    const int x0 = min((int)floor(u), wj - 2), y0 = min((int)floor(v), hj - 2);
    const float fu = u - (float)x0, fv = v - (float)y0;
    const int b00 = (y0 * wj + x0) * 3, b10 = b00 + 3 * wj;
    float acc_u = 0.0f, acc_v = 0.0f;
    for (int c = 0; c < 3; ++c) {
        const float i00 = img_j[b00 + c], i01 = img_j[b00 + 3 + c];
        const float i10 = img_j[b10 + c], i11 = img_j[b10 + 3 + c];
        const float dt = i01 - i00, db = i11 - i10;
        const float top = i00 + fu * dt, bot = i10 + fu * db;
        const float smp = top + fv * (bot - top);
        const float rc = smp - img_i[n * 3 + c];
        r[c] = rc;
        const float sg = rc > 0.0f ? 1.0f : (rc < 0.0f ? -1.0f : 0.0f);
        acc_u = acc_u + sg * (dt + fv * (db - dt));
        acc_v = acc_v + sg * (bot - top);
    }
    const float k = w / sz;
    const float k2 = k * k;
    const float dudz = (sx * g.e2 - g.e0 * sz) * k2, dvdz = (sy * g.e2 - g.e1 * sz) * k2;
    *gz = acc_u * dudz + acc_v * dvdz;
    return CW_VALID;
}

#define CW_GEOM_ARGS const float h00, const float h01, const float h02, const float h10, const float h11, \
    const float h12, const float h20, const float h21, const float h22, const float e0, const float e1, const float e2
#define CW_GEOM ((cw_geom){h00, h01, h02, h10, h11, h12, h20, h21, h22, e0, e1, e2})

__kernel void cross_warp_grad(const int width, const int height, const int wj, const int hj, CW_GEOM_ARGS,
                              const float near, const float alpha_min, const float tol,
                              const float scale, const int accumulate,
                              __global const float *depth,   /* [H, W] rendered depth of view i */
                              __global const float *alpha,   /* [H, W] its rendered alpha */
                              __global const float *img_i,   /* [H, W, 3] training image of view i */
                              __global const float *img_j,   /* [Hj, Wj, 3] training image of view j */
                              __global const float *depth_j, /* [Hj, Wj] rendered depth of view j (tol > 0) */
                              __global const float *alpha_j, /* [Hj, Wj] its rendered alpha (tol > 0) */
                              __global float *v_depth)       /* [H, W] out (or +=) */
{
    const int n = get_global_id(0);
    if (!(n < width * height)) return;
    const int y = n / width, x = n - y * width;
    float r[3], gz = 0.0f;
    float g = 0.0f;
    if (cw_pixel(x, y, width, wj, hj, CW_GEOM, near, alpha_min, tol, depth, alpha, img_i, img_j, depth_j, alpha_j,
                 r, &gz) == CW_VALID)
        g = scale * (gz / alpha[n]);
    v_depth[n] = accumulate ? v_depth[n] + g : g;
}

__kernel void cross_warp_rows(const int width, const int height, const int wj, const int hj, CW_GEOM_ARGS,
                              const float near, const float alpha_min, const float tol,
                              __global const float *depth, __global const float *alpha,
                              __global const float *img_i, __global const float *img_j,
                              __global const float *depth_j, __global const float *alpha_j,
                              __global float *rows,          /* [H] out: sum of |r| */
                              __global int *counts,          /* [H] out: valid pixels */
                              __global int *occluded)        /* [H] out: occluded pixels */
{
    const int y = get_global_id(0);
    if (!(y < height)) return;
    float acc = 0.0f;
    int cnt = 0, occ = 0;
    for (int x = 0; x < width; ++x) {
        float r[3], gz;
        const int st = cw_pixel(x, y, width, wj, hj, CW_GEOM, near, alpha_min, tol, depth, alpha, img_i, img_j,
                                depth_j, alpha_j, r, &gz);
        if (st == CW_VALID) {
            acc = acc + fabs(r[0]);
            acc = acc + fabs(r[1]);
            acc = acc + fabs(r[2]);
            cnt += 1;
        } else if (st == CW_OCCLUDED) {
            occ += 1;
        }
    }
    rows[y] = acc;
    counts[y] = cnt;
    occluded[y] = occ;
}

/* project.cl: per-Gaussian projection (EWA splatting + SH colour) and its backward.

   Computes the same function as `reings.backends.reference.project_fwd` / `project_bwd`
   (float64 numpy); the conventions are those of reings/backends/base.py and the issue spec §3:

     q <- q / |q| (w, x, y, z);  R(q) standard;  Sigma = R S S^T R^T, S = diag(exp(log_scales))
     t = Rc mu + tc;  cull unless t_z > near
     u = fx t_x / t_z + cx,  v = fy t_y / t_z + cy
     J at the gsplat-clamped (t_x/t_z, t_y/t_z);  Sigma2d = J Rc Sigma Rc^T J^T + EPS2D I
     cull unless det > 0;  conic = Sigma2d^-1 = (A, B, C)
     r = ceil(3 sqrt(lambda_max)),  lambda_max = mid + sqrt(max(0.1, mid^2 - det))
     tiles [floor((u - r)/16), ceil((u + r)/16)) (y likewise), clamped to the grid; cull if empty
     colour = max(0, SH(normalize(mu - campos)) + 0.5);  opacity = sigmoid(logit) or the override

   Kernels
     project_fwd   one work-item per Gaussian (gid); writes every output row (culled rows: zeros)
                   plus the depth sort key (float bits of t_z, or DEPTH_KEY_CULLED) and gid.
     project_bwd   one work-item per Gaussian; chains the per-Gaussian cotangents
                   (v_means2d, v_conics, v_colors, v_opacities, v_depths, packed as a [N, 10] record)
                   back to the raw fields (true derivative of project_fwd, clamps included).

   Defines
     SH_K          number of SH coefficients per channel (1, 4, 9 or 16); default 1.

   Not handled here: binning (bin.cl), blending (rasterize.cl). Guards are written positively so
   that NaN fails them; the file must be built without fast-math options.
*/

#ifndef SH_K
#define SH_K 1
#endif
#ifndef TILE_SIZE
#define TILE_SIZE 16
#endif

#define PROJ_EPS2D 0.3f            /* low-pass dilation on the 2D covariance diagonal (3DGS) */
#define PROJ_LAMBDA_FLOOR 0.1f     /* floor of the eigenvalue spread term (3DGS radius rule) */
#define PROJ_SIGMAS 3.0f           /* radius = ceil(3 sqrt(lambda_max)) */
#define PROJ_QUAT_NORM_MIN 1e-12f  /* below this |q| the rotation is undefined: cull (reference QUAT_NORM_MIN) */
#define DEPTH_KEY_CULLED 0xFFFFFFFFu /* sorts after every positive float's bits */

/* Camera record (float32, built by OpenCLBackend._camera_record):
   [0..8] Rc row-major, [9..11] tc, [12] fx, [13] fy, [14] cx, [15] cy, [16..18] camera centre,
   [19] near, [20] lim_x_pos, [21] lim_x_neg, [22] lim_y_pos, [23] lim_y_neg */
#define CAM_RECORD 24
#define V_PROJ 10 /* v record: v_mean2d xy, v_conic ABC, v_colour rgb, v_opacity, v_depth */

#define SH_C0 0.28209479177387814f
#define SH_C1 0.4886025119029199f
#define SH_C2_0 1.0925484305920792f
#define SH_C2_1 -1.0925484305920792f
#define SH_C2_2 0.31539156525252005f
#define SH_C2_3 -1.0925484305920792f
#define SH_C2_4 0.5462742152960396f
#define SH_C3_0 -0.5900435899266435f
#define SH_C3_1 2.890611442640554f
#define SH_C3_2 -0.4570457994644658f
#define SH_C3_3 0.3731763325901154f
#define SH_C3_4 -0.4570457994644658f
#define SH_C3_5 1.445305721320277f
#define SH_C3_6 -0.5900435899266435f

/* |x| <= FLT_MAX is false for NaN and +-Inf */
inline bool finite1(float x) { return fabs(x) <= FLT_MAX; }

/* All raw fields of Gaussian g finite? */
inline bool inputs_finite(int g, __global const float *means, __global const float *quats,
                          __global const float *log_scales, __global const float *opacity_logits,
                          __global const float *sh) {
    bool ok = finite1(opacity_logits[g]);
    for (int i = 0; i < 3; ++i) ok = ok && finite1(means[3 * g + i]) && finite1(log_scales[3 * g + i]);
    for (int i = 0; i < 4; ++i) ok = ok && finite1(quats[4 * g + i]);
    for (int i = 0; i < SH_K * 3; ++i) ok = ok && finite1(sh[(size_t)g * (SH_K * 3) + i]);
    return ok;
}

/* SH basis values at the unit direction d, order of 3DGS (METHOD.md §5.5) */
inline void sh_basis(float x, float y, float z, float *b) {
    b[0] = SH_C0;
#if SH_K > 1
    b[1] = -SH_C1 * y;
    b[2] = SH_C1 * z;
    b[3] = -SH_C1 * x;
#endif
#if SH_K > 4
    float xx = x * x, yy = y * y, zz = z * z;
    b[4] = SH_C2_0 * x * y;
    b[5] = SH_C2_1 * y * z;
    b[6] = SH_C2_2 * (2.0f * zz - xx - yy);
    b[7] = SH_C2_3 * x * z;
    b[8] = SH_C2_4 * (xx - yy);
#endif
#if SH_K > 9
    b[9] = SH_C3_0 * y * (3.0f * xx - yy);
    b[10] = SH_C3_1 * x * y * z;
    b[11] = SH_C3_2 * y * (4.0f * zz - xx - yy);
    b[12] = SH_C3_3 * z * (2.0f * zz - 3.0f * xx - 3.0f * yy);
    b[13] = SH_C3_4 * x * (4.0f * zz - xx - yy);
    b[14] = SH_C3_5 * z * (xx - yy);
    b[15] = SH_C3_6 * x * (xx - 3.0f * yy);
#endif
}

/* Everything project_fwd computes for one Gaussian, kept for the backward. */
typedef struct {
    float qn[4];   /* normalised quaternion (w, x, y, z) */
    float qnorm;   /* |q| */
    float R[9];    /* rotation of qn, row-major */
    float s[3];    /* exp(log_scales) */
    float M[9];    /* R S */
    float t[3];    /* camera-space mean */
    float txc, tyc;/* clamped t_x, t_y (J is evaluated there) */
    bool clx, cly; /* clamp active */
    float J[6];    /* 2x3: J00 J01 J02 / J10 J11 J12 */
    float Sc[9];   /* Rc Sigma Rc^T */
    float a, b, c; /* Sigma2d (with EPS2D) */
    float det;
    float A, B, C; /* conic */
    float u, v;
    float radius;
    int rect[4];
    float dir[3];  /* unit direction mean - campos */
    float dnorm;   /* |mean - campos| */
    float raw[3];  /* SH sum + 0.5, before the clamp */
} proj_t;

/* Forward math for one Gaussian. Returns false if the Gaussian is culled. */
inline bool project_one(int g, __global const float *means, __global const float *quats,
                        __global const float *log_scales, __global const float *opacity_logits,
                        __global const float *sh, __constant const float *cam, int width, int height,
                        proj_t *p) {
    if (!inputs_finite(g, means, quats, log_scales, opacity_logits, sh)) return false;
    float mu[3] = {means[3 * g], means[3 * g + 1], means[3 * g + 2]};

    /* camera-space mean and near cull */
    for (int i = 0; i < 3; ++i)
        p->t[i] = cam[3 * i] * mu[0] + cam[3 * i + 1] * mu[1] + cam[3 * i + 2] * mu[2] + cam[9 + i];
    const float near = cam[19];
    if (!(p->t[2] > near && p->t[2] <= FLT_MAX)) return false;  /* behind or at the near plane (NaN fails) */

    /* quaternion -> rotation; |q| computed scaled by max |q_i| so that neither huge nor tiny
       (denormal) components overflow or underflow the sum of squares */
    float w = quats[4 * g], x = quats[4 * g + 1], y = quats[4 * g + 2], z = quats[4 * g + 3];
    float qmax = fmax(fmax(fabs(w), fabs(x)), fmax(fabs(y), fabs(z)));
    if (!(qmax > 0.0f)) return false;
    float iqm = 1.0f / qmax;
    w *= iqm; x *= iqm; y *= iqm; z *= iqm;
    float n2 = w * w + x * x + y * y + z * z; /* in [1, 4] */
    float qn = sqrt(n2);
    p->qnorm = qmax * qn;
    if (!(p->qnorm >= PROJ_QUAT_NORM_MIN)) return false;  /* undefined rotation */
    w /= qn; x /= qn; y /= qn; z /= qn;
    p->qn[0] = w; p->qn[1] = x; p->qn[2] = y; p->qn[3] = z;
    float *R = p->R;
    R[0] = 1.0f - 2.0f * (y * y + z * z); R[1] = 2.0f * (x * y - w * z); R[2] = 2.0f * (x * z + w * y);
    R[3] = 2.0f * (x * y + w * z); R[4] = 1.0f - 2.0f * (x * x + z * z); R[5] = 2.0f * (y * z - w * x);
    R[6] = 2.0f * (x * z - w * y); R[7] = 2.0f * (y * z + w * x); R[8] = 1.0f - 2.0f * (x * x + y * y);

    for (int j = 0; j < 3; ++j) p->s[j] = exp(log_scales[3 * g + j]);
    for (int i = 0; i < 3; ++i)
        for (int j = 0; j < 3; ++j) p->M[3 * i + j] = R[3 * i + j] * p->s[j];

    /* world covariance Sigma = M M^T, then camera covariance Sc = Rc Sigma Rc^T = (Rc M)(Rc M)^T */
    float W[9];
    for (int i = 0; i < 3; ++i)
        for (int j = 0; j < 3; ++j)
            W[3 * i + j] = cam[3 * i] * p->M[j] + cam[3 * i + 1] * p->M[3 + j] + cam[3 * i + 2] * p->M[6 + j];
    for (int i = 0; i < 3; ++i)
        for (int j = 0; j < 3; ++j)
            p->Sc[3 * i + j] = W[3 * i] * W[3 * j] + W[3 * i + 1] * W[3 * j + 1] + W[3 * i + 2] * W[3 * j + 2];

    /* projection with the gsplat guard band */
    const float fx = cam[12], fy = cam[13], cx = cam[14], cy = cam[15];
    const float tz = p->t[2];
    const float rz = 1.0f / tz;
    float xz = p->t[0] * rz, yz = p->t[1] * rz;
    p->clx = !(xz >= -cam[21] && xz <= cam[20]);
    p->cly = !(yz >= -cam[23] && yz <= cam[22]);
    p->txc = tz * clamp(xz, -cam[21], cam[20]);
    p->tyc = tz * clamp(yz, -cam[23], cam[22]);
    p->u = fx * p->t[0] * rz + cx;
    p->v = fy * p->t[1] * rz + cy;
    float *J = p->J;
    J[0] = fx * rz; J[1] = 0.0f; J[2] = -fx * p->txc * rz * rz;
    J[3] = 0.0f; J[4] = fy * rz; J[5] = -fy * p->tyc * rz * rz;

    /* Sigma2d = J Sc J^T (+ EPS2D on the diagonal) */
    float JS[6];
    for (int i = 0; i < 2; ++i)
        for (int j = 0; j < 3; ++j)
            JS[3 * i + j] = J[3 * i] * p->Sc[j] + J[3 * i + 1] * p->Sc[3 + j] + J[3 * i + 2] * p->Sc[6 + j];
    p->a = JS[0] * J[0] + JS[1] * J[1] + JS[2] * J[2] + PROJ_EPS2D;
    p->b = JS[0] * J[3] + JS[1] * J[4] + JS[2] * J[5];
    p->c = JS[3] * J[3] + JS[4] * J[4] + JS[5] * J[5] + PROJ_EPS2D;
    if (!(finite1(p->a) && finite1(p->b) && finite1(p->c))) return false;
    /* det, conic and lambda_max computed on Sigma2d / m, m = max(a, c) >= EPS2D, so that a huge
       but representable Sigma2d does not overflow det = ac - b^2 */
    const float m = fmax(p->a, p->c), im = 1.0f / m;
    const float a1 = p->a * im, b1 = p->b * im, c1 = p->c * im;
    const float det1 = a1 * c1 - b1 * b1;
    if (!(det1 > 0.0f)) return false;  /* degenerate (NaN fails) */
    p->det = det1 * m * m;             /* may be inf for a huge Gaussian; only used via det1 */
    const float idet = 1.0f / (det1 * m);
    p->A = c1 * idet; p->B = -b1 * idet; p->C = a1 * idet;

    /* radius and tile rectangle: lambda_max = m (mid1 + sqrt(max(0.1 / m^2, mid1^2 - det1))) */
    float mid1 = 0.5f * (a1 + c1);
    float lam = m * (mid1 + sqrt(fmax(PROJ_LAMBDA_FLOOR * im * im, mid1 * mid1 - det1)));
    float r = ceil(PROJ_SIGMAS * sqrt(lam));
    if (!(lam <= FLT_MAX && finite1(p->u) && finite1(p->v) && finite1(p->A) && finite1(p->B) && finite1(p->C)))
        return false;
    p->radius = r;
    const int tiles_x = (width + TILE_SIZE - 1) / TILE_SIZE, tiles_y = (height + TILE_SIZE - 1) / TILE_SIZE;
    const float inv_tile = 1.0f / (float)TILE_SIZE;
    /* clamp in float before the int conversion (a huge r would overflow an int) */
    p->rect[0] = (int)clamp(floor((p->u - r) * inv_tile), 0.0f, (float)tiles_x);
    p->rect[1] = (int)clamp(floor((p->v - r) * inv_tile), 0.0f, (float)tiles_y);
    p->rect[2] = (int)clamp(ceil((p->u + r) * inv_tile), 0.0f, (float)tiles_x);
    p->rect[3] = (int)clamp(ceil((p->v + r) * inv_tile), 0.0f, (float)tiles_y);
    if (!(p->rect[2] > p->rect[0] && p->rect[3] > p->rect[1])) return false;  /* off screen */

    /* SH colour at the view direction */
    float d[3] = {mu[0] - cam[16], mu[1] - cam[17], mu[2] - cam[18]};
    float dn = sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
    p->dnorm = dn;
    float idn = dn > 0.0f ? 1.0f / dn : 0.0f;
    for (int i = 0; i < 3; ++i) p->dir[i] = d[i] * idn;
    float bas[SH_K];
    sh_basis(p->dir[0], p->dir[1], p->dir[2], bas);
    __global const float *shg = sh + (size_t)g * (SH_K * 3);
    for (int ch = 0; ch < 3; ++ch) {
        float acc = 0.0f;
        for (int k = 0; k < SH_K; ++k) acc += bas[k] * shg[3 * k + ch];
        p->raw[ch] = acc + 0.5f;
    }
    return finite1(p->raw[0]) && finite1(p->raw[1]) && finite1(p->raw[2]) && finite1(p->t[0]) &&
           finite1(p->t[1]);
}

/* Forward projection, one work-item per Gaussian. */
__kernel void project_fwd(const int n,
                          __global const float *means,          /* [N, 3] */
                          __global const float *quats,          /* [N, 4] (w, x, y, z) */
                          __global const float *log_scales,     /* [N, 3] */
                          __global const float *opacity_logits, /* [N] */
                          __global const float *sh,             /* [N, SH_K, 3] */
                          __constant const float *cam,          /* [CAM_RECORD] */
                          const int width, const int height,
                          const float opacity_override,         /* > 0: every opacity is this */
                          __global float *means2d,              /* [N, 2] */
                          __global float *conics,               /* [N, 3] */
                          __global float *depths,               /* [N] */
                          __global int *radii,                  /* [N] 0 = culled */
                          __global int *tile_rect,              /* [N, 4] tx0 ty0 tx1 ty1 */
                          __global float *colors,               /* [N, 3] */
                          __global float *opacities,            /* [N] */
                          __global uint *depth_keys,            /* [N] sort keys */
                          __global uint *gid_vals) {            /* [N] sort values = gid */
    const int g = get_global_id(0);
    if (g >= n) return;
    proj_t p;
    bool vis = project_one(g, means, quats, log_scales, opacity_logits, sh, cam, width, height, &p);
    gid_vals[g] = (uint)g;
    if (!vis) {
        means2d[2 * g] = 0.0f; means2d[2 * g + 1] = 0.0f;
        conics[3 * g] = 0.0f; conics[3 * g + 1] = 0.0f; conics[3 * g + 2] = 0.0f;
        depths[g] = 0.0f;
        radii[g] = 0;
        tile_rect[4 * g] = 0; tile_rect[4 * g + 1] = 0; tile_rect[4 * g + 2] = 0; tile_rect[4 * g + 3] = 0;
        colors[3 * g] = 0.0f; colors[3 * g + 1] = 0.0f; colors[3 * g + 2] = 0.0f;
        opacities[g] = 0.0f;
        depth_keys[g] = DEPTH_KEY_CULLED;
        return;
    }
    means2d[2 * g] = p.u; means2d[2 * g + 1] = p.v;
    conics[3 * g] = p.A; conics[3 * g + 1] = p.B; conics[3 * g + 2] = p.C;
    depths[g] = p.t[2];
    radii[g] = p.radius >= 2147483648.0f ? INT_MAX : (int)p.radius;  /* saturate like the reference */
    for (int i = 0; i < 4; ++i) tile_rect[4 * g + i] = p.rect[i];
    for (int ch = 0; ch < 3; ++ch) colors[3 * g + ch] = fmax(p.raw[ch], 0.0f);
    opacities[g] = opacity_override > 0.0f ? opacity_override : 1.0f / (1.0f + exp(-opacity_logits[g]));
    depth_keys[g] = as_uint(p.t[2]);  /* t_z > near > 0: the float bits order like the floats */
}

/* Backward projection, one work-item per Gaussian: raw-field gradients from the per-Gaussian
   cotangents. grad_mask bits: 1 means, 2 quats, 4 log_scales, 8 opacity_logits, 16 sh (a field
   whose bit is clear gets zeros). Culled Gaussians (radii == 0) get zeros. */
__kernel void project_bwd(const int n,
                          __global const float *means,          /* [N, 3] */
                          __global const float *quats,          /* [N, 4] */
                          __global const float *log_scales,     /* [N, 3] */
                          __global const float *opacity_logits, /* [N] */
                          __global const float *sh,             /* [N, SH_K, 3] */
                          __constant const float *cam,          /* [CAM_RECORD] */
                          const int width, const int height,
                          const float opacity_override,         /* > 0: opacity grad is zero */
                          const int grad_mask,
                          __global const int *radii,            /* [N] from project_fwd */
                          __global const float *v_proj,         /* [N, V_PROJ] */
                          __global float *v_means,              /* [N, 3] */
                          __global float *v_quats,              /* [N, 4] */
                          __global float *v_log_scales,         /* [N, 3] */
                          __global float *v_opacity_logits,     /* [N] */
                          __global float *v_sh) {               /* [N, SH_K, 3] */
    const int g = get_global_id(0);
    if (g >= n) return;
    proj_t p;
    bool vis = radii[g] > 0 &&
               project_one(g, means, quats, log_scales, opacity_logits, sh, cam, width, height, &p);
    __global float *vsh = v_sh + (size_t)g * (SH_K * 3);
    if (!vis) {
        for (int i = 0; i < 3; ++i) { v_means[3 * g + i] = 0.0f; v_log_scales[3 * g + i] = 0.0f; }
        for (int i = 0; i < 4; ++i) v_quats[4 * g + i] = 0.0f;
        v_opacity_logits[g] = 0.0f;
        for (int i = 0; i < SH_K * 3; ++i) vsh[i] = 0.0f;
        return;
    }
    /* The backward is linear in the cotangents. Huge ones (a colour near FLT_MAX makes its
       neighbours' cotangents overflow) are scaled by an exact power of two, the chain runs on the
       scaled values and the results are scaled back: they may overflow to +-inf, never to
       inf - inf = NaN. +-inf cotangents saturate at +-FLT_MAX first. NaN stays NaN. */
    __global const float *vp = v_proj + (size_t)g * V_PROJ;
    float vin[V_PROJ], vmax = 0.0f;
    for (int i = 0; i < V_PROJ; ++i) {
        float x = vp[i];
        x = isinf(x) ? copysign(FLT_MAX, x) : x;
        vmax = fmax(vmax, fabs(x));
        vin[i] = x;
    }
    float vscale = 1.0f;
    if (vmax > 0x1p60f) {
        int e;
        frexp(vmax, &e);
        vscale = ldexp(1.0f, e - 2); /* <= 2^126 (finite); vmax / vscale in [2, 4) */
        for (int i = 0; i < V_PROJ; ++i) vin[i] /= vscale;
    }
    const float v_u = vin[0], v_v = vin[1], v_A = vin[2], v_B = vin[3], v_C = vin[4];
    const float v_col[3] = {vin[5], vin[6], vin[7]};
    const float v_op = vin[8], v_depth = vin[9];

    /* opacity */
    float vlogit = 0.0f;
    if (!(opacity_override > 0.0f)) {
        float op = 1.0f / (1.0f + exp(-opacity_logits[g]));
        vlogit = v_op * op * (1.0f - op);
    }
    v_opacity_logits[g] = (grad_mask & 8) ? vlogit * vscale : 0.0f;

    /* colour: zero gradient where the 0 clamp is active */
    float vc[3];
    for (int ch = 0; ch < 3; ++ch) vc[ch] = p.raw[ch] >= 0.0f ? v_col[ch] : 0.0f;
    float bas[SH_K];
    sh_basis(p.dir[0], p.dir[1], p.dir[2], bas);
    for (int k = 0; k < SH_K; ++k)
        for (int ch = 0; ch < 3; ++ch) vsh[3 * k + ch] = (grad_mask & 16) ? bas[k] * vc[ch] * vscale : 0.0f;

    float vmu[3] = {0.0f, 0.0f, 0.0f};
#if SH_K > 1
    {
        /* d colour / d dir: v_b[k] = sum_ch sh[k][ch] vc[ch], then the basis Jacobian */
        __global const float *shg = sh + (size_t)g * (SH_K * 3);
        float vb[SH_K];
        for (int k = 0; k < SH_K; ++k) vb[k] = shg[3 * k] * vc[0] + shg[3 * k + 1] * vc[1] + shg[3 * k + 2] * vc[2];
        const float x = p.dir[0], y = p.dir[1], z = p.dir[2];
        float gx = -SH_C1 * vb[3], gy = -SH_C1 * vb[1], gz = SH_C1 * vb[2];
#if SH_K > 4
        const float xx = x * x, yy = y * y, zz = z * z;
        gx += SH_C2_0 * y * vb[4] + SH_C2_2 * (-2.0f * x) * vb[6] + SH_C2_3 * z * vb[7] + SH_C2_4 * 2.0f * x * vb[8];
        gy += SH_C2_0 * x * vb[4] + SH_C2_1 * z * vb[5] + SH_C2_2 * (-2.0f * y) * vb[6] - SH_C2_4 * 2.0f * y * vb[8];
        gz += SH_C2_1 * y * vb[5] + SH_C2_2 * 4.0f * z * vb[6] + SH_C2_3 * x * vb[7];
#endif
#if SH_K > 9
        gx += SH_C3_0 * 6.0f * x * y * vb[9] + SH_C3_1 * y * z * vb[10] + SH_C3_2 * (-2.0f * x * y) * vb[11] +
              SH_C3_3 * (-6.0f * x * z) * vb[12] + SH_C3_4 * (4.0f * zz - 3.0f * xx - yy) * vb[13] +
              SH_C3_5 * 2.0f * x * z * vb[14] + SH_C3_6 * 3.0f * (xx - yy) * vb[15];
        gy += SH_C3_0 * 3.0f * (xx - yy) * vb[9] + SH_C3_1 * x * z * vb[10] +
              SH_C3_2 * (4.0f * zz - xx - 3.0f * yy) * vb[11] + SH_C3_3 * (-6.0f * y * z) * vb[12] +
              SH_C3_4 * (-2.0f * x * y) * vb[13] + SH_C3_5 * (-2.0f * y * z) * vb[14] +
              SH_C3_6 * (-6.0f * x * y) * vb[15];
        gz += SH_C3_1 * x * y * vb[10] + SH_C3_2 * 8.0f * y * z * vb[11] +
              SH_C3_3 * (6.0f * zz - 3.0f * xx - 3.0f * yy) * vb[12] + SH_C3_4 * 8.0f * x * z * vb[13] +
              SH_C3_5 * (xx - yy) * vb[14];
#endif
        /* through dir = d / |d| */
        if (p.dnorm > 0.0f) {
            float dot = x * gx + y * gy + z * gz, idn = 1.0f / p.dnorm;
            vmu[0] += (gx - x * dot) * idn;
            vmu[1] += (gy - y * dot) * idn;
            vmu[2] += (gz - z * dot) * idn;
        }
    }
#endif

    /* conic -> Sigma2d (a, b, c): conic = inverse of [[a, b], [b, c]] */
    const float A = p.A, B = p.B, C = p.C;
    const float va = -(A * A * v_A + A * B * v_B + B * B * v_C);
    const float vb2 = -(2.0f * A * B * v_A + (A * C + B * B) * v_B + 2.0f * B * C * v_C);
    const float vc2 = -(B * B * v_A + B * C * v_B + C * C * v_C);
    /* V: gradient w.r.t. the symmetric 2x2 matrix with independent entries (b split in two) */
    const float V00 = va, V01 = 0.5f * vb2, V11 = vc2;

    /* Sigma2d = J Sc J^T: v_Sc = J^T V J, v_J = 2 V J Sc */
    const float *J = p.J;
    float VJ[6]; /* V J, 2x3 */
    for (int j = 0; j < 3; ++j) {
        VJ[j] = V00 * J[j] + V01 * J[3 + j];
        VJ[3 + j] = V01 * J[j] + V11 * J[3 + j];
    }
    float vJ[6];
    for (int i = 0; i < 2; ++i)
        for (int j = 0; j < 3; ++j)
            vJ[3 * i + j] = 2.0f * (VJ[3 * i] * p.Sc[j] + VJ[3 * i + 1] * p.Sc[3 + j] + VJ[3 * i + 2] * p.Sc[6 + j]);
    float vSc[9];
    for (int i = 0; i < 3; ++i)
        for (int j = 0; j < 3; ++j) vSc[3 * i + j] = J[i] * VJ[j] + J[3 + i] * VJ[3 + j];

    /* camera-space mean: u, v, depth and J */
    const float fx = cam[12], fy = cam[13];
    const float tz = p.t[2], rz = 1.0f / tz, rz2 = rz * rz, rz3 = rz2 * rz;
    float vt[3];
    vt[0] = fx * rz * v_u;
    vt[1] = fy * rz * v_v;
    vt[2] = -fx * p.t[0] * rz2 * v_u - fy * p.t[1] * rz2 * v_v + v_depth;
    /* J00 = fx/tz, J02 = -fx txc/tz^2 (txc = tx unclamped, tz*L clamped) */
    vt[2] += -fx * rz2 * vJ[0] - fy * rz2 * vJ[4];
    if (p.clx) {
        vt[2] += fx * p.txc * rz3 * vJ[2];
    } else {
        vt[0] += -fx * rz2 * vJ[2];
        vt[2] += 2.0f * fx * p.t[0] * rz3 * vJ[2];
    }
    if (p.cly) {
        vt[2] += fy * p.tyc * rz3 * vJ[5];
    } else {
        vt[1] += -fy * rz2 * vJ[5];
        vt[2] += 2.0f * fy * p.t[1] * rz3 * vJ[5];
    }
    /* t = Rc mu + tc */
    for (int j = 0; j < 3; ++j) vmu[j] += cam[j] * vt[0] + cam[3 + j] * vt[1] + cam[6 + j] * vt[2];
    for (int j = 0; j < 3; ++j) v_means[3 * g + j] = (grad_mask & 1) ? vmu[j] * vscale : 0.0f;

    /* Sc = Rc Sigma Rc^T: v_Sigma = Rc^T v_Sc Rc */
    float T1[9], vS[9];
    for (int i = 0; i < 3; ++i)
        for (int j = 0; j < 3; ++j) /* T1 = Rc^T v_Sc */
            T1[3 * i + j] = cam[i] * vSc[j] + cam[3 + i] * vSc[3 + j] + cam[6 + i] * vSc[6 + j];
    for (int i = 0; i < 3; ++i)
        for (int j = 0; j < 3; ++j) /* vS = T1 Rc */
            vS[3 * i + j] = T1[3 * i] * cam[j] + T1[3 * i + 1] * cam[3 + j] + T1[3 * i + 2] * cam[6 + j];
    /* Sigma = M M^T: v_M = (vS + vS^T) M */
    float vM[9];
    for (int i = 0; i < 3; ++i)
        for (int j = 0; j < 3; ++j) {
            float acc = 0.0f;
            for (int k = 0; k < 3; ++k) acc += (vS[3 * i + k] + vS[3 * k + i]) * p.M[3 * k + j];
            vM[3 * i + j] = acc;
        }
    /* M = R S */
    for (int j = 0; j < 3; ++j) {
        float vs = p.R[j] * vM[j] + p.R[3 + j] * vM[3 + j] + p.R[6 + j] * vM[6 + j];
        v_log_scales[3 * g + j] = (grad_mask & 4) ? vs * p.s[j] * vscale : 0.0f;
    }
    float G[9];
    for (int i = 0; i < 3; ++i)
        for (int j = 0; j < 3; ++j) G[3 * i + j] = vM[3 * i + j] * p.s[j];
    /* R(qn) -> qn */
    const float w = p.qn[0], x = p.qn[1], y = p.qn[2], z = p.qn[3];
    float vq[4];
    vq[0] = 2.0f * (-z * G[1] + y * G[2] + z * G[3] - x * G[5] - y * G[6] + x * G[7]);
    vq[1] = 2.0f * (y * G[1] + z * G[2] + y * G[3] - 2.0f * x * G[4] - w * G[5] + z * G[6] + w * G[7] - 2.0f * x * G[8]);
    vq[2] = 2.0f * (-2.0f * y * G[0] + x * G[1] + w * G[2] + x * G[3] + z * G[5] - w * G[6] + z * G[7] - 2.0f * y * G[8]);
    vq[3] = 2.0f * (-2.0f * z * G[0] - w * G[1] + x * G[2] + w * G[3] - 2.0f * z * G[4] + y * G[5] + x * G[6] + y * G[7]);
    /* qn = q / |q| */
    float dq = w * vq[0] + x * vq[1] + y * vq[2] + z * vq[3];
    float iq = 1.0f / p.qnorm;
    for (int i = 0; i < 4; ++i) v_quats[4 * g + i] = (grad_mask & 2) ? (vq[i] - p.qn[i] * dq) * iq * vscale : 0.0f;
}

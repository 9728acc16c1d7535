/* mse.cl: the mean squared error of a rendered image against a training image, for the train PSNR
   of the loop's logging iterations (reings/train.py History.train_psnr): the device trainer's
   `read_mse` reads H row sums instead of the whole image.

   Twin: reings.backends.reference_loss.mse_rows (float64), tests/test_mse.py.

   Kernels
     mse_rows   global (H): per row y the sum over its 3W floats, left to right, of (x - y)^2, the
                difference and the square taken in `real` (double where the device has
                cl_khr_fp64, MSE_FP64=1, as numpy's float64 is; else float); the host sums the rows
                in float64 and divides by 3HW.

   Defines
     MSE_FP64   1: the sums in double; 0 (default): in float.
*/
#pragma OPENCL FP_CONTRACT OFF

#ifndef MSE_FP64
#define MSE_FP64 0
#endif
#if MSE_FP64
#pragma OPENCL EXTENSION cl_khr_fp64 : enable
typedef double real;
#else
typedef float real;
#endif

__kernel void mse_rows(const int width, const int height,
                       __global const float *x,     /* [H, W, 3] rendered */
                       __global const float *y,     /* [H, W, 3] training image */
                       __global real *rows)         /* [H] out */
{
    const int r = get_global_id(0);
    if (!(r < height)) return;
    const int m = 3 * width;
    __global const float *xr = x + (size_t)r * m;
    __global const float *yr = y + (size_t)r * m;
    real acc = (real)0;
    for (int i = 0; i < m; ++i) {
        const real d = (real)xr[i] - (real)yr[i];
        acc += d * d;
    }
    rows[r] = acc;
}

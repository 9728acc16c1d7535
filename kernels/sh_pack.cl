/* sh_pack.cl: the projection's SH input at the active degree, from the training state's two SH
   parameter groups (the device trainer, reings/backends/opencl/trainer.py; redone only after the
   SH groups were stepped or the degree changed).

   Must match reings.backends.reference_state.sh_pack (tests/test_device_fit.py).

   Kernels
     sh_pack   [N,1,3] sh_dc + the first k-1 rows of [N,kmax-1,3] sh_rest -> [N,k,3]; one
               work-item per output float.
*/
#pragma OPENCL FP_CONTRACT OFF

__kernel void sh_pack(const int n, const int k, const int kmax,
                      __global const float *sh_dc,    /* [N, 1, 3] */
                      __global const float *sh_rest,  /* [N, kmax - 1, 3] */
                      __global float *sh)             /* [N, k, 3], 1 <= k <= kmax */
{
    const int i = get_global_id(0);
    const int row_len = 3 * k;
    if (!(i < n * row_len)) return;
    const int r = i / row_len, c = i - r * row_len;
    sh[i] = c < 3 ? sh_dc[3 * r + c] : sh_rest[r * 3 * (kmax - 1) + (c - 3)];
}

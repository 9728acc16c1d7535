"""Named capability predicates for OpenCL devices (pyopencl.characterize style).

Only this module looks at vendor / platform strings. Everything else asks a predicate, and kernels
see the answers as `-D` defines (`build_defines`).
"""
from __future__ import annotations


def platform_name(device) -> str:
    return device.platform.name


def is_pocl(device) -> bool:
    """PoCL: CPU work-groups run as loops over work-items; no forward-progress guarantee between
    work-groups, so a look-back may wait only on a work-group that is already running (sort.cl's
    onesweep takes its block ids from an atomic counter; the CPU schedule has no look-back at all;
    docs/perf_notes.md §4.1, §20)."""
    return "Portable Computing Language" in device.platform.name


def is_oclgrind(device) -> bool:
    """Oclgrind: the strict OpenCL 1.2 simulator used for memory-safety tests."""
    return "Oclgrind" in device.platform.name


def is_nvidia(device) -> bool:
    """NVIDIA's OpenCL: `cl_nv_pragma_unroll` is the standard detection (docs/perf_notes.md §4.4); inline PTX
    (`red.global.add.f32`, `shfl.sync`) compiles there."""
    return "cl_nv_pragma_unroll" in device.extensions


def volatile_status_words(device) -> bool:
    """Whether a look-back may read other work-groups' status words with volatile loads (one aligned
    32-bit word each) instead of atomics: NVIDIA (volatile global loads are not cached in L1; measured
    in docs/perf_notes.md §20) and PoCL on a CPU (coherent caches). Elsewhere atomics, the portable form
    (PoCL's GPU drivers, other vendors; Oclgrind reports the volatile form as the data race it is by
    OpenCL's memory model)."""
    return is_nvidia(device) or (is_pocl(device) and is_cpu(device))


def clang_builtins(device) -> bool:
    """PoCL on a CPU: its clang (LLVM 14 in pip's PoCL 3.0) compiles two builtins the CPU schedule takes where
    the compiler has them (`__has_builtin`): __builtin_reduce_or for the mask tests (any8 / any16, common.h: one
    AVX-512 mask test instead of a shuffle tree) and __builtin_prefetch for the rasterizer's next records
    (RASTER_PREFETCH, rasterize.cl); docs/perf_notes.md §30. Not Oclgrind (its interpreter has neither
    intrinsic) nor GPUs (their schedules use neither; NVIDIA's compiler refuses __builtin_prefetch of a __global
    pointer: OpenCL C's address spaces are distinct there, PoCL's CPUs have one flat space)."""
    return is_pocl(device) and is_cpu(device)


def is_cpu(device) -> bool:
    import pyopencl as cl

    return bool(device.type & cl.device_type.CPU)


def has_fp32_global_atomic_add(device) -> bool:
    """cl_ext_float_atomics with fp32 global add (PoCL >= 5); absent on pip PoCL 3.0 and NVIDIA."""
    return "cl_ext_float_atomics" in device.extensions


def opencl_c_version(device) -> tuple[int, int]:
    # e.g. "OpenCL C 1.2 PoCL" / "OpenCL C 1.2 "
    try:
        v = device.opencl_c_version.split()[2]
        major, minor = v.split(".")[:2]
        return int(major), int(minor)
    except Exception:  # pragma: no cover - malformed driver strings
        return (1, 2)


def local_mem_size(device) -> int:
    return int(device.local_mem_size)


def max_work_group_size(device) -> int:
    return int(device.max_work_group_size)


def build_defines(device) -> dict[str, int]:
    """The capability defines every kernel file is built with.

    REINGS_CPU_SCHEDULE  1 on CPU devices (PoCL): row/tile-per-work-item schedules, no barriers.
    REINGS_NV_PTX        1 on NVIDIA: inline PTX red.global.add.f32 and shfl.sync are allowed.
    REINGS_FLOAT_ATOMICS 1 where cl_ext_float_atomics provides a native fp32 global add.
    REINGS_CLANG_BUILTINS 1 where the CPU schedule may take clang's __builtin_reduce_or / __builtin_prefetch.
    """
    return {
        "REINGS_CPU_SCHEDULE": int(is_cpu(device)),
        "REINGS_NV_PTX": int(is_nvidia(device)),
        "REINGS_FLOAT_ATOMICS": int(has_fp32_global_atomic_add(device)),
        "REINGS_CLANG_BUILTINS": int(clang_builtins(device)),
    }

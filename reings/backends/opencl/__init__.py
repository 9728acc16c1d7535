"""OpenCL backend. The only package that imports pyopencl."""

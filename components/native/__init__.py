"""Compile-on-first-use C++ kernels loaded with ctypes (shared by the components that have one)."""

"""The compiled (numba) kernels of rSHOSM: the memory (Algorithm 1), the dense evidence and the beam."""

"""Estimation: motion models, measurement conversion, Kalman update, IMM and VDF, the
small linear-algebra kernels and their scratch buffers. Pure NumPy: imports neither
Zenoh nor anything of tracking (tests/test_layers.py). Every fast kernel has its
textbook form in tests/reference/estimation.py, and tests compare the two.
"""

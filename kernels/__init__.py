"""OpenCL sources (kernels/*.cl and headers), installed as package data of clrender.kernels."""

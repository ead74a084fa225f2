"""NDRF (Wan et al., CVPR 2023): duplex meshes from a teacher, per-vertex features, a 2x2
convolutional shader. Mesh extraction, baked format, numpy reference and OpenCL renderer,
torch training. The rendering contract is docs/ndrf.md."""

"""NGP-RT: config, baked format, numpy reference and OpenCL renderers, torch training and
baking. The rendering contract is docs/ngprt.md."""

/* Rays through pixel centres: origins and unit directions, (H*W, 3) float each. */
#include "camera.h"

__kernel void generate_rays(__global const float *cam, const int width, const int height,
                            __global float *origins, __global float *dirs)
{
    const int px = get_global_id(0), py = get_global_id(1);
    if (px >= width || py >= height) return;
    const int i = py * width + px;
    const float3 o = camera_ray_origin(cam), d = camera_ray_dir(cam, px, py);
    origins[3 * i] = o.x; origins[3 * i + 1] = o.y; origins[3 * i + 2] = o.z;
    dirs[3 * i] = d.x; dirs[3 * i + 1] = d.y; dirs[3 * i + 2] = d.z;
}

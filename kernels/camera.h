/* Ray generation shared by every kernel that starts from pixels.
 * Mirrors clrender/camera.py:generate_rays bit for bit (no FP contraction,
 * correctly rounded division and sqrt requested at build time). */
#ifndef CLRENDER_CAMERA_H
#define CLRENDER_CAMERA_H
#pragma OPENCL FP_CONTRACT OFF

/* cam: [fx, fy, cx, cy, R row-major (9), origin (3), pad] as Camera.packed(). */
inline float3 camera_ray_dir(__global const float *cam, int px, int py)
{
    const float a = ((float)px + 0.5f - cam[2]) / cam[0];
    const float b = -(((float)py + 0.5f - cam[3]) / cam[1]);
    float3 d;
    d.x = cam[4] * a + cam[5] * b - cam[6];
    d.y = cam[7] * a + cam[8] * b - cam[9];
    d.z = cam[10] * a + cam[11] * b - cam[12];
    const float norm = sqrt(d.x * d.x + d.y * d.y + d.z * d.z);
    return (float3)(d.x / norm, d.y / norm, d.z / norm);
}

inline float3 camera_ray_origin(__global const float *cam)
{
    return (float3)(cam[13], cam[14], cam[15]);
}
#endif

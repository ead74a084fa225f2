/* Ray generation shared by every kernel that starts from pixels.
 * Mirrors clrender/camera.py:generate_rays bit for bit (no FP contraction,
 * correctly rounded division and sqrt requested at build time). */
#ifndef CLRENDER_CAMERA_H
#define CLRENDER_CAMERA_H
#pragma OPENCL FP_CONTRACT OFF

/* cam: [fx, fy, cx, cy, R row-major (9), origin (3), pad] as Camera.packed().
 * The unit direction of pixel (px, py)'s ray into d[0..2] (scalars: PoCL runs float3
 * arithmetic in hot loops markedly slower). */
inline void camera_ray_dir_into(__global const float *cam, int px, int py, float *d)
{
    const float a = ((float)px + 0.5f - cam[2]) / cam[0];
    const float b = -(((float)py + 0.5f - cam[3]) / cam[1]);
    const float x = cam[4] * a + cam[5] * b - cam[6];
    const float y = cam[7] * a + cam[8] * b - cam[9];
    const float z = cam[10] * a + cam[11] * b - cam[12];
    const float norm = sqrt(x * x + y * y + z * z);
    d[0] = x / norm;
    d[1] = y / norm;
    d[2] = z / norm;
}

/* camera_ray_dir_into as a float3. */
inline float3 camera_ray_dir(__global const float *cam, int px, int py)
{
    float d[3];
    camera_ray_dir_into(cam, px, py, d);
    return vload3(0, d);
}

inline float3 camera_ray_origin(__global const float *cam)
{
    return (float3)(cam[13], cam[14], cam[15]);
}
#endif

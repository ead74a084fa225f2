/* Ray generation shared by every kernel that starts from pixels.
 * Mirrors clrender/camera.py:generate_rays bit for bit (no FP contraction,
 * correctly rounded division and sqrt requested at build time). */
#ifndef CLRENDER_CAMERA_H
#define CLRENDER_CAMERA_H
#pragma OPENCL FP_CONTRACT OFF

/* The camera record, CAM_FLOATS floats as clrender/camera.py's Camera.packed() writes it:
 * focal lengths, principal point, the camera-to-world rotation R row-major (R[i][j] at
 * CAM_R + 3 i + j) and the origin. */
#define CAM_FX 0
#define CAM_FY 1
#define CAM_CX 2
#define CAM_CY 3
#define CAM_R 4
#define CAM_O 13
#define CAM_FLOATS 16

/* cam: the camera record.
 * The unit direction of pixel (px, py)'s ray into d[0..2] (scalars: PoCL runs float3
 * arithmetic in hot loops markedly slower). */
inline void camera_ray_dir_into(__global const float *cam, int px, int py, float *d)
{
    const float a = ((float)px + 0.5f - cam[CAM_CX]) / cam[CAM_FX];
    const float b = -(((float)py + 0.5f - cam[CAM_CY]) / cam[CAM_FY]);
    const float x = cam[CAM_R + 0] * a + cam[CAM_R + 1] * b - cam[CAM_R + 2];
    const float y = cam[CAM_R + 3] * a + cam[CAM_R + 4] * b - cam[CAM_R + 5];
    const float z = cam[CAM_R + 6] * a + cam[CAM_R + 7] * b - cam[CAM_R + 8];
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
    return (float3)(cam[CAM_O + 0], cam[CAM_O + 1], cam[CAM_O + 2]);
}
#endif

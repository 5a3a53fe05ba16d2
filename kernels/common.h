// Shared OpenCL helpers, #include'd by every .cl file of geosynth.
//
// Data types are chosen at build time (one program per dtype, cached per context):
//   GS_U8 defined: T = uchar data, S = uint scores, W = uint weights (exact integers)
//   otherwise:     T = float data, S = float scores, W = float weights
#ifndef GEOSYNTH_COMMON_H
#define GEOSYNTH_COMMON_H

#ifdef GS_U8
typedef uchar T;
typedef uchar16 T16;
typedef uint S;
typedef uint2 S2;
typedef uint4 S4;
typedef uint8 S8;
typedef uint16 S16;
typedef uint W;
typedef uint16 W16;

inline S sq_diff(T a, T b) { S d = (S)abs_diff(a, b); return d * d; }
inline S16 sq_diff16(T16 a, T16 b) { S16 d = convert_uint16(abs_diff(a, b)); return d * d; }
#else
typedef float T;
typedef float16 T16;
typedef float S;
typedef float2 S2;
typedef float4 S4;
typedef float8 S8;
typedef float16 S16;
typedef float W;
typedef float16 W16;

inline S sq_diff(T a, T b) { S d = a - b; return d * d; }
inline S16 sq_diff16(T16 a, T16 b) { S16 d = a - b; return d * d; }
#endif

inline S hsum16(S16 v)
{
    S8 a = v.lo + v.hi;
    S4 b = a.lo + a.hi;
    S2 c = b.lo + b.hi;
    return c.x + c.y;
}

// Selection modes, shared with kernels/ssd.py.
#define SELECT_LEQ 0
#define SELECT_LT 1
#define SELECT_EQ 2

inline int is_selected(S s, S thr, int mode)
{
    return mode == SELECT_LEQ ? s <= thr : (mode == SELECT_LT ? s < thr : s == thr);
}

#endif

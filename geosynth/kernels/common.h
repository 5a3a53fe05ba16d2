// Shared OpenCL helpers, #include'd by every .cl file of geosynth.
//
// Data types are chosen at build time (one program per dtype, cached per context):
//   GS_U8 defined: T = uchar data, S = uint scores, W = uint weights (exact integers)
//   otherwise:     T = float data, S = float scores, W = float weights
//
// Performance note (PoCL 3 on the CPU, measured): OpenCL builtins such as vload16,
// vstore16, convert_*, min, fma and abs_diff are not inlined there but called, which
// made hot loops 3-20x slower. Hot code therefore uses plain operators, vector loads
// through pointer types of reduced alignment (LOAD16) and __builtin_convertvector.
// No OpenCL builtin is called on a 16-wide vector at all: PoCL 3.0 on a CPU with AVX-512
// that its LLVM does not know (AMD Zen 4, taken for "znver3") aborts the process, or
// crashes, generating code for any of them (sqrt, select, all, vstore16, ... on float16 /
// int16; 8-wide calls are fine), so the tests on such a machine abort.
#ifndef GEOSYNTH_COMMON_H
#define GEOSYNTH_COMMON_H

typedef float f32x16u __attribute__((ext_vector_type(16), aligned(4)));
typedef uchar u8x16u __attribute__((ext_vector_type(16), aligned(1)));
typedef uint u32x16u __attribute__((ext_vector_type(16), aligned(4)));
typedef int i32x16u __attribute__((ext_vector_type(16), aligned(4)));

#ifdef GS_U8
typedef uchar T;
typedef uint S;
typedef uint W;
typedef int16 E16;   // signed differences, 16 lanes
typedef uint16 S16;  // score accumulators, 16 lanes
typedef u32x16u Sx16u;
#define LOADS16(p) (*(const __global Sx16u*)(p))  // 16 scores
// 16 consecutive elements at p (any alignment), widened to int
#define LOAD16(p) __builtin_convertvector(*(const __global u8x16u*)(p), int16)
#define LOADW16(p) (*(const __global u32x16u*)(p))
#define SQ16(e) __builtin_convertvector((e) * (e), uint16)
#define SPLAT16(v) ((E16)((int)(v)))
#define SQ1(a, b) ((uint)(((int)(a) - (int)(b)) * ((int)(a) - (int)(b))))
// Float lanes holding integers: exact while a lane's sum stays below 2^24.
#define LOADF16(p) __builtin_convertvector(*(const __global u8x16u*)(p), float16)
#define F16_TO_S16(a) __builtin_convertvector((a), uint16)
#else
typedef float T;
typedef float S;
typedef float W;
typedef float16 E16;
typedef float16 S16;
typedef f32x16u Sx16u;
#define LOADS16(p) (*(const __global Sx16u*)(p))  // 16 scores
#define LOAD16(p) (*(const __global f32x16u*)(p))
#define LOADW16(p) (*(const __global f32x16u*)(p))
#define SQ16(e) ((e) * (e))
#define SPLAT16(v) ((E16)(v))
#define SQ1(a, b) (((a) - (b)) * ((a) - (b)))
#define LOADF16(p) LOAD16(p)
#define F16_TO_S16(a) (a)
#endif

#ifdef GS_U8
typedef uint8 S8;
typedef uint4 S4;
typedef uint2 S2;
#else
typedef float8 S8;
typedef float4 S4;
typedef float2 S2;
#endif

__attribute__((always_inline)) inline S hsum16(S16 v)
{
    const S8 a = v.lo + v.hi;
    const S4 b = a.lo + a.hi;
    const S2 c = b.lo + b.hi;
    return c.x + c.y;
}

// Unrolling helpers: REPn(M) expands M(0) ... M(n-1); REP6_R(M, r) expands M(r, 0) ... M(r, 5).
#define REP2(M) M(0) M(1)
#define REP4(M) M(0) M(1) M(2) M(3)
#define REP8(M) M(0) M(1) M(2) M(3) M(4) M(5) M(6) M(7)
#define REP6(M) M(0) M(1) M(2) M(3) M(4) M(5)
#define REP6_R(M, r) M(r, 0) M(r, 1) M(r, 2) M(r, 3) M(r, 4) M(r, 5)

#define MIN_INT(a, b) ((a) < (b) ? (a) : (b))

// Whether any lane of a comparison mask is set (no builtin: see the note above). Always
// inlined: an int16 passed by value to a call changes the ABI without AVX-512 (a
// compiler warning on such CPUs), and the call would cost more than its four ORs.
__attribute__((always_inline)) inline int any16(int16 m)
{
    const int8 a = m.lo | m.hi;
    const int4 b = a.lo | a.hi;
    const int2 c = b.lo | b.hi;
    return (c.x | c.y) != 0;
}

// Whether every lane of a comparison mask is set (all() on int16: see the note above).
__attribute__((always_inline)) inline int all16(int16 m)
{
    const int8 a = m.lo & m.hi;
    const int4 b = a.lo & a.hi;
    const int2 c = b.lo & b.hi;
    return (c.x & c.y) < 0;
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

/* mesh_events.c compiled for x86-64 CPUs with AVX2 and FMA (x86-64-v3): the same event arithmetic
 * with fused multiply-adds and wider registers. The exported functions carry the suffix _avx2; the
 * host calls them only where sfc_simd_supported() (operators/mesh/events_compiled.py). */
#if defined(__x86_64__) && (defined(__GNUC__) || defined(__clang__))
#pragma GCC target("avx2,fma")
#define SFC_EXPORT(name) name##_avx2
#include "mesh_events.c"
#endif

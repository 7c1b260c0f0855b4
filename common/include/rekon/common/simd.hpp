#pragma once
// REKON_SIMD_CLONES before a hot per-pixel or per-voxel loop function compiles
// it twice, for x86-64-v3 (AVX2, FMA: 8 floats a lane, gathers) and for the
// baseline; the loader picks the clone the CPU runs (GCC function
// multiversioning through an ifunc). The binaries stay portable. `flatten`
// inlines every call into each clone: without it GCC calls the baseline
// build of a large inline kernel from the AVX2 clone. Off for
// other compilers and architectures, and under the sanitizers (clang).
#if defined(__GNUC__) && !defined(__clang__) && defined(__x86_64__) && defined(__linux__)
#define REKON_SIMD_CLONES __attribute__((target_clones("arch=x86-64-v3", "default"), flatten))
#else
#define REKON_SIMD_CLONES
#endif

namespace rekon {

// Selects that vectorise: std::fmax/fmin keep IEEE NaN rules, which GCC does
// not vectorise; a > b ? a : b compiles to one max/min instruction (b for a NaN a).
inline float selectMax(float a, float b) { return a > b ? a : b; }
inline float selectMin(float a, float b) { return a < b ? a : b; }

}  // namespace rekon

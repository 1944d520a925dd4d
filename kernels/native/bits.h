// Bit operations for the CPU (clang) and CUDA (NVRTC) alike. kernels/traversal.py pastes this file into
// the body of each of its native functions, so a module may hold it several times: hence the guard.
#ifndef USDBAKE_CTZ
#ifdef __CUDA_ARCH__
#define USDBAKE_CTZ(x) (__ffs(x) - 1)
#define USDBAKE_POPCOUNT(x) __popc(x)
#define USDBAKE_FLOAT_BITS(x) __float_as_int(x)
#define USDBAKE_BITS_FLOAT(x) __int_as_float(x)
#else
#define USDBAKE_CTZ(x) __builtin_ctz(x)
#define USDBAKE_POPCOUNT(x) __builtin_popcount(x)
#define USDBAKE_FLOAT_BITS(x) __builtin_bit_cast(int, x)
#define USDBAKE_BITS_FLOAT(x) __builtin_bit_cast(float, x)
#endif
#endif

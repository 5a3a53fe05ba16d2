#!/usr/bin/env bash
# cpu_matrix.sh CMD...: run CMD three times, with NumPy and OpenBLAS acting as this CPU
# (native), as an AVX2 machine and as an SSE4 machine, and print each exit status; exit
# with the last failure's status. Host float steps that NumPy or OpenBLAS dispatch by the
# CPU (BLAS products, LAPACK's solve/lstsq/eigh, float32 and (AVX-512) float64
# transcendentals) round differently on each: an output or a test that changes between
# them changes on a user's machine too (issue 40). `make test-cpus` runs the suite's
# reproducibility tests this way.
# What it cannot emulate: AVX-512 on a machine without it (native is then AVX2), and the
# Warp and PoCL kernels, which LLVM compiles for the real CPU.
[ $# -gt 0 ] || { sed -n 2,10p "$0"; exit 2; }
names=(native avx2 sse4)
settings=(
  ""
  "NPY_DISABLE_CPU_FEATURES=X86_V4 AVX512_ICL AVX512_SPR|OPENBLAS_CORETYPE=Haswell"
  "NPY_DISABLE_CPU_FEATURES=X86_V3 X86_V4 AVX512_ICL AVX512_SPR|OPENBLAS_CORETYPE=Nehalem"
)
worst=0; summary=()
for i in 0 1 2; do
  IFS='|' read -r -a vars <<< "${settings[$i]}"
  echo "=== ${names[$i]} ${vars[*]}"
  env "${vars[@]}" "$@"; rc=$?
  summary+=("${names[$i]}: exit $rc"); [ $rc -eq 0 ] || worst=$rc
done
printf '%s\n' "=== summary" "${summary[@]}"
exit $worst

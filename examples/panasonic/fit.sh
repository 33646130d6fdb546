#!/usr/bin/env bash
# Fit the Panasonic NCR18650PF (shared data set, doi:10.17632/wykht8y7tg.1) into one BPX cell.
#
#   examples/panasonic/fit.sh DATA_DIR OUT.bpx.json
#
# Equilibrium from the 25 degC C/20 test (6-term positive-OCP correction), then the reduced dynamic parameter
# set of benchmarks/bench_panasonic.py on the 25 degC US06, every test from full charge (--soc0 1).
# Score the result with: python benchmarks/bench_panasonic_temps.py OUT.bpx.json
set -euo pipefail
if [[ $# -ne 2 ]]; then
    echo "usage: $0 DATA_DIR OUT.bpx.json" >&2
    exit 2
fi
data=$1
out=$2
for f in 25degC_C20_OCV.mat 25degC_US06.mat; do
    [[ -f "$data/$f" ]] || { echo "error: $data/$f not found" >&2; exit 2; }
done
battlab fit "$data/25degC_C20_OCV.mat" "$data/25degC_US06.mat" \
    --cell nca18650 --ocp-terms 6 --rated-capacity 2.9 --soc0 1 \
    --params D_s_n,D_s_p,R_f_n,k_p,kappa_scale,D_e_scale,eps_e_s --max-iter 15 \
    -o "$out"

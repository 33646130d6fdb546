#!/usr/bin/env bash
# Fit the Panasonic NCR18650PF (shared data set, doi:10.17632/wykht8y7tg.1) into one BPX cell for 25, 10 and 0 degC.
#
#   examples/panasonic/fit.sh DATA_DIR OUT.bpx.json
#
# 0. prepare.py: the C/20 test with its logged current corrected by the offset its charge balance shows (-9.9 mA:
#    its charge back to 4.2 V returns 2.61 of the 2.99 Ah its discharge counted; uncorrected, the fitted capacity is
#    3.01 Ah and the branches 70-150 mV apart, corrected 2.82 Ah and a near constant 40 mV apart); the start cell
#    nca18650 with a fixed R_c of 15 mOhm, below the 25-31 mOhm the HPPC shows 0.1 s into a pulse.
# 1. Equilibrium from the corrected C/20 test: the mean of both branches (the hysteresis and the C/20 overpotential
#    cancel to first order; the mean agrees with the 25 degC HPPC rest voltages to 6 mV RMS), a 4-term positive-OCP
#    correction (8 terms fit the curve to 1.9 mV but use half of the negative electrode's range: the two electrodes'
#    curves trade), SOC 1 = the state the lab's full charge leaves.
# 2. age.py: the cell as it was on 2017-03-20 (the 25 degC drive tests) from the fade between the 25 degC HPPC
#    (03-11) and the C/20 test (05-08): 0.026 %/day from the rest voltages, capacity x 1.013 (2.836 Ah).
# 3. Dynamics on the 25 degC US06 from full charge with the contact-resistance extension on (its R_c on top of the
#    fixed 15 mOhm) and the solid diffusivities' stoichiometry dependence (log-slopes b_n, b_p), exact sensitivities.
# 4. The dynamics' activation energies from the 10 and 0 degC US06 (--arrhenius; the 0 degC refit starts where the
#    10 degC one carries the values, and needs its 16 evaluations to come from 114 to 62 mV).
# 5. Heat capacity (C1 and C2 by one factor) and heat transfer to the ambient from the logged surface temperature.
# The HWFET and HPPC tests are left out (held out for scoring). Score with benchmarks/bench_panasonic_temps.py.
# Measured (2 cores, tests running beside it: 4 min 19 s with a warm model cache, 9 min with an empty one; the drive
# tests read one logging interval after each grid time, see battlab.identify.experiments.read_delay): after step 3 the
# 25 degC US06 (training) 44.8 -> 25.0 mV (b_n 2.8, b_p -1.7), converged with k_p, R_f_n, kappa_scale, D_e_scale and
# eps_e_s on bounds (missing structure, not too few evaluations). Step 4: E_D_s_n 41.7, E_D_s_p 19.2, E_kappa 31.2,
# E_D_e 24.3 kJ/mol, E_k_p clipped at 0. The written cell, whole test / to 90 % of its charge
# (benchmarks/bench_panasonic_temps.py): HWFET 25 degC 33.8 / 11.6 mV (96 % reached), 10 degC 41.4 / 21.0, 0 degC 65.4
# / 56.1; US06 25/10/0 degC 25.8 / 31.5 / 70.3 mV (all reached). Without the stoichiometry-dependent D_s (no refit)
# the six drive tests' mean is 13 mV worse; with the nominal activation energies instead of step 4's it is 8 mV better
# on them (HWFET 0 degC 43 mV) but the 0 degC US06 stops at 75 % (benchmarks/bench_panasonic_ablation.py): energies
# fitted to US06 alone do not carry to HWFET. A capacity per file in the refits (--per-file-ageing capacity) puts the
# 0 degC US06 at 1.03 of the 25 degC one, so the fade between the test dates does not explain the cold misfit.
set -euo pipefail
if [[ $# -ne 2 ]]; then
    echo "usage: $0 DATA_DIR OUT.bpx.json" >&2
    exit 2
fi
data=$1
out=$2
for f in 25degC_C20_OCV.mat 25degC_HPPC.mat 25degC_US06.mat 10degC_US06.mat 0degC_US06.mat; do
    [[ -f "$data/$f" ]] || { echo "error: $data/$f not found" >&2; exit 2; }
done
here=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
drive=("$data/25degC_US06.mat" "$data/10degC_US06.mat" "$data/0degC_US06.mat")
names=D_s_n,D_s_p,R_f_n,k_p,kappa_scale,D_e_scale,eps_e_s,contact_resistance.R_c,solid_diffusion.b_n,solid_diffusion.b_p

python "$here/prepare.py" "$data" "$work"

battlab fit "$work/c20.bdf.csv" --cell "$work/start.bpx.json" --ocp-terms 4 --rated-capacity 2.9 --ocv-branch both \
    --full-charge ocv-start --params none -o "$work/equilibrium.bpx.json"

python "$here/age.py" "$data" "$work/c20.bdf.csv" "$work/equilibrium.bpx.json" 2017-03-20 "$work/aged.bpx.json"

battlab fit "$data/25degC_US06.mat" --cell "$work/aged.bpx.json" --extension contact_resistance:R_c=0.012 \
    --extension solid_diffusion:b_p=-1 --soc0 1 \
    --params "$names" --max-iter 12 -o "$work/dynamics.bpx.json"

battlab fit "${drive[@]}" --cell "$work/dynamics.bpx.json" --soc0 1 --params "$names" --arrhenius --max-iter 16 \
    -o "$work/arrhenius.bpx.json"

battlab fit "${drive[@]}" --cell "$work/arrhenius.bpx.json" --soc0 1 \
    --params none --fit-values temperature:C1+C2,h2a --dt 2 --max-iter 6 -o "$out"

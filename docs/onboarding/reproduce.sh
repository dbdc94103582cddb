#!/usr/bin/env bash
# Every command of docs/onboarding.md, in order: rig files, held-out comparisons, gap reports,
# controller gains and the re-derivation of the shipped rig files from their recordings.
# Run from the repository root with .venv active (or the console scripts on PATH); the
# recordings are read from ../shared/data/real and never copied: derived tables and reports go
# to $W (default /tmp/aeropend-onboarding). Serial, about 6 min on two cores.
set -uo pipefail   # not -e: a command that fails is reported in the log and the rest still runs
R=${R:-../shared/data/real}
W=${W:-/tmp/aeropend-onboarding}
O=docs/onboarding
mkdir -p "$W"
step() { echo; echo "### $*"; }

# ---------------------------------------------------------------- matheusbucater (dc_hbridge)
D=$R/matheusbucater__aeropendulo
step matheusbucater: rig new, rig fit on the sawtooth and the free fall, held-out step
rig new --actuator dc_hbridge --name matheusbucater --overwrite -o $O/matheusbucater/stated.yaml \
    --stated pendulum.mass=23g pendulum.com_distance=10cm pendulum.thrust_arm=12cm actuator.v_supply=9V motor.gear_ratio=1
rig fit $O/matheusbucater/stated.yaml $D/aeropendulum.csv:matheusbucater_sawtooth \
    $D/pendulum.csv:$O/matheusbucater/free_fall.yaml -o $O/matheusbucater/fitted.yaml --overwrite -q
rig fit $O/matheusbucater/stated.yaml $D/aeropendulum_step.csv:matheusbucater_step -o $W/mb_oracle_step.yaml --overwrite -q
compare $D/aeropendulum_step.csv:matheusbucater_step --rig $O/matheusbucater/fitted.yaml $W/mb_oracle_step.yaml \
    --label fitted oracle -o $W/mb_cmp_step --overwrite --no-plots
step matheusbucater: the other split: fit on the step and the free fall, held-out sawtooth
rig fit $O/matheusbucater/stated.yaml $D/aeropendulum_step.csv:matheusbucater_step \
    $D/pendulum.csv:$O/matheusbucater/free_fall.yaml -o $O/matheusbucater/fitted_step_fall.yaml --overwrite -q
rig fit $O/matheusbucater/stated.yaml $D/aeropendulum.csv:matheusbucater_sawtooth -o $W/mb_oracle_saw.yaml --overwrite -q
compare $D/aeropendulum.csv:matheusbucater_sawtooth --rig $O/matheusbucater/fitted_step_fall.yaml $W/mb_oracle_saw.yaml \
    $O/matheusbucater/fitted.yaml --label fitted_step_fall oracle fitted_saw_fall -o $W/mb_cmp_saw --overwrite --no-plots
rig check $O/matheusbucater/fitted.yaml $D/aeropendulum.csv:matheusbucater_sawtooth $D/aeropendulum_step.csv:matheusbucater_step
# gap: the step (a constant command from rest) held out; then the sawtooth split in time
gap $D/aeropendulum.csv:matheusbucater_sawtooth --held-out $D/aeropendulum_step.csv:matheusbucater_step \
    --rig $O/matheusbucater/fitted.yaml -o $W/mb_gap_step --overwrite -q
gap $D/aeropendulum.csv:matheusbucater_sawtooth --split 0.6 --rig $O/matheusbucater/fitted.yaml -o $W/mb_gap --overwrite -q
design_gains --rig $O/matheusbucater/fitted.yaml

# ---------------------------------------------------------------- dondi01 (Quanser Aero 2)
D=$R/dondi01__quanser_aero2_project
step dondi01: rig new, rig fit on the 8 V step, the motor-off log held out
rig new --actuator voltage_amplifier --name dondi01_aero2 --overwrite -o $O/dondi01/stated.yaml \
    --stated actuator.v_max=24V motor.R_a=8.2ohm motor.K_t=0.042 motor.K_omega=0.042 motor.gear_ratio=1
rig fit $O/dondi01/stated.yaml $D/NO_WEIGHTS_4V.csv.gz:$O/dondi01/aero2_pitch_up.yaml -o $O/dondi01/fitted.yaml --overwrite -q
rig fit $O/dondi01/stated.yaml $D/SATURATION_ANGLE.csv:$O/dondi01/aero2_motor_off.yaml -o $W/dondi01_oracle_sat.yaml --overwrite -q
compare $D/SATURATION_ANGLE.csv:$O/dondi01/aero2_motor_off.yaml --rig $O/dondi01/fitted.yaml $W/dondi01_oracle_sat.yaml \
    --label fitted oracle -o $W/dondi01_cmp_sat --overwrite --no-plots
rig check $O/dondi01/fitted.yaml $D/NO_WEIGHTS_4V.csv.gz:$O/dondi01/aero2_pitch_up.yaml
gap $D/NO_WEIGHTS_4V.csv.gz:$O/dondi01/aero2_pitch_up.yaml --split 0.6 --rig $O/dondi01/fitted.yaml -o $W/dondi01_gap --overwrite -q
design_gains --rig $O/dondi01/fitted.yaml

# ---------------------------------------------------------------- finnferdinand (Quanser Aero 2, ±24 V)
D=$R/finnferdinand__orbital-stabilization-quanser-aero
step finnferdinand: balance table from the transcribed steady states, rig new, rig fit
awk -F, 'NR==1{print "command,angle_rad"} NR>1 && $1=="main" {printf "%.6f,%s\n", ($2+24)/48, $4}' \
    $D/steady_state_pitch_vs_motor_speed_voltage.csv > $W/finnferdinand_balance.csv
rig new --actuator voltage_amplifier --name finnferdinand_aero2 --overwrite -o $O/finnferdinand/stated.yaml \
    --stated actuator.v_max=48V actuator.v_offset=-24V motor.R_a=8.2ohm motor.K_t=0.042 motor.K_omega=0.042 motor.gear_ratio=1
rig fit $O/finnferdinand/stated.yaml $W/finnferdinand_balance.csv \
    $D/pitch_coefficients/pitch_coefficients.csv:$O/finnferdinand/aero2_pitch_pm24V.yaml -o $O/finnferdinand/fitted.yaml --overwrite -q
rig check $O/finnferdinand/fitted.yaml $W/finnferdinand_balance.csv $D/pitch_coefficients/pitch_coefficients.csv:$O/finnferdinand/aero2_pitch_pm24V.yaml
gap $D/pitch_coefficients/pitch_coefficients.csv:$O/finnferdinand/aero2_pitch_pm24V.yaml --split 0.6 \
    --rig $O/finnferdinand/fitted.yaml -o $W/finnferdinand_gap --overwrite -q
design_gains --rig $O/finnferdinand/fitted.yaml

# ---------------------------------------------------------------- YangZhu (Quanser AERO)
D=$R/YangZhu-uestc__Quanser-AERO-2-DOF-helicopter-Model-Identification
step yangzhu: thrust table from the transcribed torques, rig new, rig fit
awk -F, 'NR==1{print "command,thrust_N"} NR>1 {printf "%.6f,%.8f\n", $1/24, $2/0.15875}' \
    $D/actuator_taup_vs_Vp_static.csv > $W/yangzhu_thrust.csv
rig new --actuator voltage_amplifier --name yangzhu_aero --overwrite -o $O/yangzhu/stated.yaml \
    --stated actuator.v_max=24V motor.gear_ratio=1
rig fit $O/yangzhu/stated.yaml $W/yangzhu_thrust.csv $D/aero_pitch_step_16p5V_1kHz.csv.gz:yangzhu_pitch_step \
    -o $O/yangzhu/fitted.yaml --overwrite -q
rig check $O/yangzhu/fitted.yaml $D/aero_pitch_step_16p5V_1kHz.csv.gz:yangzhu_pitch_step
gap $D/aero_pitch_step_16p5V_1kHz.csv.gz:yangzhu_pitch_step --split 0.6 --rig $O/yangzhu/fitted.yaml \
    -o $W/yangzhu_gap --overwrite -q
design_gains --rig $O/yangzhu/fitted.yaml

# ---------------------------------------------------------------- cychitivav (hobby)
D=$R/cychitivav__aeropendulum
step cychitivav: thrust table in volts / 5 V, rig new, rig fit
awk -F, 'NR==1{print "command,thrust_N"} NR>1 {printf "%.6f,%s\n", $1/5, $2}' \
    $D/thrust_voltage_with_header.csv > $W/cychitivav_thrust.csv
rig new --actuator voltage_amplifier --name cychitivav --overwrite -o $O/cychitivav/stated.yaml \
    --stated actuator.v_max=5V actuator.v_offset=0V motor.gear_ratio=1
rig fit $O/cychitivav/stated.yaml $W/cychitivav_thrust.csv $D/data_pendulum_with_header.csv:$O/cychitivav/free_swing.yaml \
    -o $O/cychitivav/fitted.yaml --overwrite -q
rig check $O/cychitivav/fitted.yaml $D/data_pendulum_with_header.csv:$O/cychitivav/free_swing.yaml
gap $D/data_pendulum_with_header.csv:$O/cychitivav/free_swing.yaml --split 0.6 --rig $O/cychitivav/fitted.yaml \
    -o $W/cychitivav_gap --overwrite -q
design_gains --rig $O/cychitivav/fitted.yaml

# ---------------------------------------------------------------- shipped rig files re-derived
S=src/aeropend_sim/aeropend_sim/rigs
refit() {  # shipped rig, '|'-separated keys: their source becomes "to be fitted (rig fit)"
    sed -E "/^  ($2):/ s/source: \"[^\"]*\"/source: \"to be fitted (rig fit)\"/" $S/$1.yaml
}
step shipped: aeroshield_rig
refit aeroshield_rig 'mgd_over_J|c_over_J|L_over_J|dead_zone' > $O/shipped/aeroshield_refit_start.yaml
D=$R/gergelytakacs__AutomationShield/AeroShield
rig fit $O/shipped/aeroshield_refit_start.yaml $D/Identification_Data.csv:aeroshield_ident \
    $D/Identification_Data2.csv:aeroshield_ident2 -o $O/shipped/aeroshield_refit.yaml --overwrite -q
compare $D/Identification_Data.csv:aeroshield_ident $D/Identification_Data2.csv:aeroshield_ident2 \
    --rig aeroshield_rig $O/shipped/aeroshield_refit.yaml --label shipped refit -o $W/aeroshield_cmp --overwrite --no-plots
step shipped: etchepareborda_rig
refit etchepareborda_rig 'mgd_over_J|c_over_J|L_over_J' > $O/shipped/etchepareborda_refit_start.yaml
D=$R/BA-Etchepareborda__adaptive-control-aeropendulum
rig fit $O/shipped/etchepareborda_refit_start.yaml $D/openloop_steps_0_100_180.csv:etchepareborda_openloop \
    $D/openloop_steps_0_100_130.csv:etchepareborda_openloop $D/openloop_gaussian_pwm.csv:etchepareborda_openloop \
    $D/openloop_random_binary_80_120.csv:etchepareborda_openloop -o $O/shipped/etchepareborda_refit.yaml --overwrite -q
compare $D/openloop_steps_0_100_180.csv $D/openloop_steps_0_100_130.csv $D/openloop_gaussian_pwm.csv \
    $D/openloop_random_binary_80_120.csv --preset etchepareborda_openloop \
    --rig etchepareborda_rig $O/shipped/etchepareborda_refit.yaml --label shipped refit -o $W/etchepareborda_cmp --overwrite --no-plots
step shipped: jahoyosr_rig '(rig fit takes angles in the model frame: the preset shifts by -90 deg, the start file drops recording_frame)'
refit jahoyosr_rig 'mgd_over_J|c_over_J|L_over_J|dead_zone|coulomb_over_J' | sed -E '/^recording_frame:/,/^  theta_offset/d' \
    > $O/shipped/jahoyosr_refit_start.yaml
D=$R/jahoyosr__Aeropendulum
rig fit $O/shipped/jahoyosr_refit_start.yaml $D/sheet_Hoja3_pwm_steps_openloop.csv:$O/shipped/jahoyosr_hoja3_model_frame.yaml \
    -o $O/shipped/jahoyosr_refit.yaml --overwrite -q
compare $D/sheet_Hoja3_pwm_steps_openloop.csv:jahoyosr_hoja3 --rig jahoyosr_rig -o $W/jahoyosr_cmp_shipped --overwrite --no-plots
compare $D/sheet_Hoja3_pwm_steps_openloop.csv:$O/shipped/jahoyosr_hoja3_model_frame.yaml --rig $O/shipped/jahoyosr_refit.yaml \
    --label refit -o $W/jahoyosr_cmp_refit --overwrite --no-plots

#!/usr/bin/env bash
# `cmake --install` of a build into a fresh prefix, then what a user of the installed tree does: the files are where
# they should be, the installed binaries find the installed configuration, and a project of its own builds against
# find_package(cellcal) / cellcal::core and runs. Usage: check_install.sh BUILD_DIR WORK_DIR
set -euo pipefail
build=$1
work=$2
here=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)
rm -rf "$work"
mkdir -p "$work"
prefix=$work/prefix
cmake --install "$build" --prefix "$prefix" >"$work/install.log"

fail() { echo "check_install: $*" >&2; exit 1; }
for f in bin/cellcal bin/cellcal_tracker_adapter bin/cellcal_joint_state_adapter bin/cellcal_calibration_engine \
         bin/cellcal_compensation_publisher bin/cellcal_rsi_bridge lib/libcellcal_core.a lib/libcellcal_servo.so include/cellcal/servo_compensation.h include/cellcal/core/identification/calibration.hpp \
         include/cellcal/core/identification/rls.hpp lib/cmake/cellcal/cellcalConfig.cmake lib/cmake/cellcal/cellcalConfigVersion.cmake \
         lib/cmake/cellcal/cellcalTargets.cmake share/cellcal/idl/cellcal_msgs.idl share/cellcal/config/cell.yaml \
         share/cellcal/config/dds/cellcal_qos.xml share/cellcal/config/robots/staubli_tx60.yaml \
         share/cellcal/config/security/permissions.xml share/cellcal/config/sysctl/60-cellcal.conf; do
  [[ -f $prefix/$f ]] || fail "$f was not installed"
done
[[ -x $prefix/share/cellcal/config/security/make_pki.sh ]] || fail "make_pki.sh is not executable"
# The library is the core only: experiments, scenarios and dataset readers (lab/) stay in the build.
[[ ! -e $prefix/include/cellcal/lab ]] || fail "lab/ headers were installed with cellcal::core"
! find "$prefix/include" -name 'paper_experiment.hpp' -o -name 'ipa_dataset.hpp' | grep -q . ||
  fail "experiment or dataset headers were installed"
# Installed binaries default to the installed configuration, not the source tree they were built from.
"$prefix/bin/cellcal_calibration_engine" --help >"$work/engine_help.txt"
grep -q "$prefix/share/cellcal/config/cell.yaml" "$work/engine_help.txt" ||
  fail "the installed engine's default --config is not $prefix/share/cellcal/config/cell.yaml: $(grep -- --config "$work/engine_help.txt")"

cmake -S "$here/consumer" -B "$work/consumer" -DCMAKE_PREFIX_PATH="$prefix" -DCMAKE_BUILD_TYPE=Release >"$work/consumer_configure.log" ||
  { cat "$work/consumer_configure.log"; fail "the consumer project did not configure against $prefix"; }
cmake --build "$work/consumer" >"$work/consumer_build.log" 2>&1 ||
  { cat "$work/consumer_build.log"; fail "the consumer project did not build against $prefix"; }
(cd "$work" && "$work/consumer/consumer")  # it writes its measurement file there
# The servo library from C, on the installed cell file's robot: a copy beside it (its relative paths hold) on a domain
# no test uses.
servo_cell=$prefix/share/cellcal/config/servo_check.yaml
sed -e 's/domain_id: [0-9]*/domain_id: 231/' "$prefix/share/cellcal/config/cell.yaml" >"$servo_cell"
grep -q "domain_id: 231" "$servo_cell" || fail "the installed cell.yaml has no dds domain_id"
"$work/consumer/servo_consumer" "$servo_cell" ||
  fail "the C servo consumer failed against $prefix"
"$work/consumer/servo_loops" "$servo_cell" ||
  fail "the C++ servo loops (ros2_control, ur_rtde) failed against $prefix"
echo "check_install: installed tree in $prefix is complete and usable"

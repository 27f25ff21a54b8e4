#!/usr/bin/env bash
# Build the package with colcon (colcon-core + colcon-ros from PyPI) in a temporary
# workspace, as a ROS user would, and check the install layout `ros2 run` / `ros2 launch`
# rely on: executables in lib/thermal_imu_calib, package.xml + config + launch in share.
set -euo pipefail
here="$(cd "$(dirname "$0")/.." && pwd)"
ws="$(mktemp -d)"
trap 'rm -rf "$ws"' EXIT
pkg="$ws/src/thermal_imu_calib"
mkdir -p "$pkg"
# a clean copy of the tracked files (what a clone holds)
(cd "$here" && git ls-files -z | xargs -0 cp --parents -t "$pkg/")
cd "$ws"
colcon build --base-paths src --event-handlers console_direct- > "$ws/build.log" 2>&1 \
  || { tail -n 40 "$ws/build.log"; echo "colcon build failed"; exit 1; }
lib="install/thermal_imu_calib/lib/thermal_imu_calib"
share="install/thermal_imu_calib/share/thermal_imu_calib"
missing=0
for exe in compensator_node calibrator_node bringup thermal-imu-calib; do
  if [ -x "$lib/$exe" ]; then echo "ok   $lib/$exe"; else echo "MISSING $lib/$exe"; missing=1; fi
done
for f in package.xml config/compensator.yaml config/calibrator.yaml \
         launch/thermal_imu_calib.launch.py; do
  if [ -f "$share/$f" ]; then echo "ok   $share/$f"; else echo "MISSING $share/$f"; missing=1; fi
done
marker="install/thermal_imu_calib/share/ament_index/resource_index/packages/thermal_imu_calib"
if [ -f "$marker" ]; then echo "ok   $marker"; else echo "MISSING $marker"; missing=1; fi
exit $missing

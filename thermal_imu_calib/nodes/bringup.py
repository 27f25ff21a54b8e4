"""Run the compensator and the calibrator in one process, on one executor thread.

A SingleThreadedExecutor, not a MultiThreadedExecutor: with rclpy 7.1.6 the latter
dispatches too slowly for a 1 kHz IMU and makes batched takes unsafe (see
``common.drain``). The calibrator's estimation still runs on its own worker thread, so
the compensator and the data collection keep flowing during ``~/calibrate``.

Parameters for both come from the usual ``--ros-args`` (e.g. ``--params-file`` with the
sections ``thermal_imu_compensator`` and ``thermal_imu_calibrator``).
"""

from . import process
from .calibrator import CalibratorNode
from .compensator import CompensatorNode


def main(args=None):
    """Run both nodes until shutdown."""
    process.exit_process(process.run_nodes([CompensatorNode, CalibratorNode], args))


if __name__ == '__main__':
    main()

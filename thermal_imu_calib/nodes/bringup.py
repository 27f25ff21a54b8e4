"""Run the compensator and the calibrator in one process, on one executor thread.

A SingleThreadedExecutor, not a MultiThreadedExecutor: with rclpy 7.1.6 the latter
dispatches too slowly for a 1 kHz IMU and makes batched takes unsafe (see
``common.drain``). The calibrator's estimation still runs on its own worker thread, so
the compensator and the data collection keep flowing during ``~/calibrate``.

Parameters for both come from the usual ``--ros-args`` (e.g. ``--params-file`` with the
sections ``thermal_imu_compensator`` and ``thermal_imu_calibrator``).
"""

import rclpy
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor

from .calibrator import CalibratorNode
from .compensator import CompensatorNode


def main(args=None):
    """Run both nodes until shutdown."""
    rclpy.init(args=args)
    nodes = []
    try:
        nodes.append(CompensatorNode())
        nodes.append(CalibratorNode())
        executor = SingleThreadedExecutor()
        for node in nodes:
            executor.add_node(node)
        executor.spin()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        for node in nodes:
            node.destroy_node()
        rclpy.try_shutdown()


if __name__ == '__main__':
    main()

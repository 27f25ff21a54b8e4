"""Thin rclpy adapters around the core: the compensator and calibrator nodes and bringup.

``compensator.CompensatorNode`` applies a calibration to ``imu/data_raw``;
``calibrator.CalibratorNode`` collects stationary statistics and estimates one;
``bringup`` runs both in one process. ``common`` holds QoS, parameter, conversion and
diagnostics helpers. No estimation or compensation maths lives here.
"""

"""Use cases, one module each; the command line, the nodes and the fleet call these.

``calibrate`` (logs or a live collection to a calibration file: ``calibrate_logs``,
``calibrate_collected``), ``collect`` (the stationary windows of a log), ``compensate``
(a log with compensated Imu messages added), ``evaluate`` (static errors before and after),
``noise`` (the Allan noise of a log), ``report`` (the windows a report draws) and ``fleet``
(the map and reduce steps the Dask runner submits). No ROS import: the adapters parse,
call one of these and format.
"""

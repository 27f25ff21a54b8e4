"""Lifelong calibration: learn the thermal model from everyday stops (no ROS import).

``store`` keeps the holds (recent raw windows, older ones compacted per temperature bin and
orientation cluster, persisted to a directory), ``hints`` turns motion hints into the
intervals the robot was commanded still, ``gate`` scores a calibration on held-out holds and
decides a swap, ``manager`` ties them to ``app.calibrate.calibrate_collected`` (the CLI's
calibrate) and to a fleet-format registry, with ``config`` (its settings), ``trigger`` (when
to re-estimate), ``variants`` (the estimate's other fits), ``alarm`` (the change alarm) and
``files`` (the directory's files). The node adapter is ``nodes/lifelong.py``.
"""

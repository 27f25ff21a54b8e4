"""Selection: the ``auto`` choice between model families by held-out validation.

``select`` compares candidates on held-out holds; ``gyro_select`` picks
the default gyroscope model. Built on the fits in estimation/.
"""

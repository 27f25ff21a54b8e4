"""Collection: everything that runs while data streams, live or offline.

Stationary detection (``stationary``), window statistics (``segments``),
pose changes between holds (``motion``) and the spike gate and robust
statistics (``outliers``). Imports only io/, models/ and the helpers.
"""

"""Identification of the ball model from measured trajectories (``tt-identify``).

Modules: ``data`` (loading and cleaning), ``segment`` (flights, bounces, racket contacts),
``fitting`` (eq. 9 least squares over initial states and global parameters), ``effects``
(the library of candidate physical effects), ``evaluate`` (held-out errors and effect
selection), ``report`` (report.json, report.md, plots) and ``cli``. None imports rclpy.
"""

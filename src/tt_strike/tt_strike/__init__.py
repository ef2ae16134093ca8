"""Strike solver of the tt stack: racket velocity and orientation that send the ball to a target
zone.
"""

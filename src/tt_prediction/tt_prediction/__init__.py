"""Ball model of the tt stack: flight with drag and Magnus, table and racket rebounds, event-
driven prediction of bounce, hit point and landing zone, and identification from measured data.
"""

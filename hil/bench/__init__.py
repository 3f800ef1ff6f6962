"""The bench: ``lockstep`` (plant and controller advancing together in virtual time, scored
against the plant's truth) and ``stimulus`` (replayable stimuli run on it).

Import the module you need; this package imports nothing.
"""

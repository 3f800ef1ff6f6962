"""Real-bench signals: stimulus an instrument can play (VCD, CSV) and gate captures scored against
truth. The capture files themselves are read by ``hil.recording`` (``capture``, ``vcd``, ``formats``);
errors of bad input are its ``errors.SignalError``."""

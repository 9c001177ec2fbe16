"""The bench: the bench-log format (:mod:`.log`), the serial logger (:mod:`.logger`) and the
virtual bench (:mod:`.virtual`) that stands in for hardware."""

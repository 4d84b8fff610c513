"""Teleoperation between the controller and the slave: the delayed channel (:mod:`.channel`), wave
variables (:mod:`.wave`) and the link that joins them into the servo loop (:mod:`.link`)."""

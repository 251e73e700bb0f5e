"""GNSS receivers: one backend interface (backend.GnssBackend), one module per source, and the parts they share.

Backends (what the daemon's GNSS task reads, all alike):
* serial_port: a receiver on a UART/USB speaking u-blox UBX and/or NMEA (through stream's decoder);
* mavlink: the autopilot's GPS_RAW_INT (GLOBAL_POSITION_INT as an opt-in fallback);
* replay: a GNSS recording released in step with an IMU replay;
* sim: the simulated scenario receiver (a pty device, scenario) read through serial_port, as hardware is.

Shared: validation (the edge validator every fix passes), ubx / nmea (protocol <-> GnssFix), stream (bytes ->
fixes), recording (the CSV format), log (the on-vehicle GNSS log), simulated (the pty receiver device).
"""

"""Live inputs of a vehicle agent: receiver streams (UBX, RTCM 3), NTRIP corrections, UWB over UDP.

`urls` parses and validates the source URLs, `status` is what every source reports (connected,
reconnects, bytes, age), `sources` holds the byte transports (file, TCP, serial), `ntrip` the NTRIP
client, `decode` turns frames into epochs and ephemerides incrementally, `uwb` reads the UWB line
protocol. Layer: a shell beside `runtime` and `store` (docs/architecture.md).
"""

"""Blueprint Subsea Oculus M-series multibeam heads (M750d, M1200d, M3000d): the Ethernet codec
(`protocol`), the virtual head (`virtual`), the driver
(`driver`), ``.oculus`` logs (`logfile`) and what the head is to `mitsonar.devices.registry`
(`registration`). The models' published figures are `mitsonar.presets.oculus`."""

"""Tritech Micron: the SeaNet codec (`seanet`), the driver (`driver`), the virtual head
(`virtual`), passive recording (`passive`), the assembly of scanlines into scans (`assembler`) and
what the head is to `mitsonar.devices.registry` (`registration`)."""

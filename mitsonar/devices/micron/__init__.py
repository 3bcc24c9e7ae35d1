"""Tritech Micron: the SeaNet codec (`seanet`), the driver (`driver`), the virtual head
(`virtual`) and the assembly of scanlines into scans (`assembler`)."""

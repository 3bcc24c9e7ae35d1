"""The receiver: what a head does with the echoes it hears (electronics: TVG, gain, A/D window,
8/4-bit bytes; the scene's speckle) and how much its bytes look like a real head's (realism)."""

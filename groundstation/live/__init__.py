"""The live side: byte sources, fanout, recorder sink and the daemon that wires them."""

"""The serial streaming driver (``driver: {kind: serial}``): a microcontroller running
firmware/ streams hardware-timed samples over USB serial (docs/drivers.md)."""

"""`marlin-temp job`: the print job of a printer that `marlin-temp serve` owns: read it, follow it, steer it."""

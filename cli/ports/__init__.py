"""Where a printer is: `marlin-temp ports`, the serial ports of this machine, and `marlin-temp sim`, a simulated
printer served on a port of its own (`options`)."""

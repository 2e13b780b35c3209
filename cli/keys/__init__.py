"""`marlin-temp keys`: the OctoPrint API's application keys of a service, decided by its owner."""

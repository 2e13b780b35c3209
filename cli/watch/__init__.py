"""`marlin-temp watch`: the live view of one printer, or of several as a farm (`command`), and its command
line (`options`); its model and rendering are shared and live in `common`, the farm rows in `farm.view`."""

"""`marlin-temp print FILE`: streaming a G-code file (`command`), the plan made from the file before
anything is sent and the lazy reading of it afterwards (`plan`), the pure progress view (`view`), and the
command line (`options`)."""

"""`marlin-temp bench`: read-only measurements of the link to the user's own printer (`command`), and its
command line (`options`)."""

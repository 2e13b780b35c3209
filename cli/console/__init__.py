"""Talking G-code to the printer by hand: `marlin-temp terminal`, the interactive console (`terminal`), and
`marlin-temp send`, commands one after another with their replies (`send`); the command lines of both
(`options`)."""

"""A print farm: many printers on one event loop, each kept connected by its own supervisor (`supervisor`), and a
bridge that publishes them to an MQTT broker and takes commands from it (`bridge`, `commands`), configured from
options or a TOML file (`config`)."""

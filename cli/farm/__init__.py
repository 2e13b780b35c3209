"""`marlin-temp farm`, many printers bridged to an MQTT broker (`command`, over the library's
`marlin_aio.farm`; its command line in `options`), and the farm view of `marlin-temp watch` with several
printers (`view`)."""

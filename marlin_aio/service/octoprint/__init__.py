"""The part of OctoPrint's REST API that slicers, Home Assistant and OctoPrint's client libraries use, served by
`marlin-temp serve --octoprint`.

PrusaSlicer, OrcaSlicer and Cura's "OctoPrint" host type upload a file and start it (`GET /api/version`, then
`POST /api/files/local` with `print=true`); Home Assistant's OctoPrint integration gets a key through the app-key
flow, reads `/api/settings`, `/api/printer` and `/api/job`, and sends `POST /api/job` (pause, resume, cancel) and
heater targets. Each request is answered from the service's own state (its farm's printer: the latest reading,
the print running) and acts through the service's table of verbs, as the socket's and MQTT's clients do, so a
print started here is the same print `marlin-temp serve` shows everywhere.

One module a resource: `server` (version, connection, settings, profiles, and the administrative calls a key of
the service may not make), `printer` (state, temperatures, targets, print head, tool, commands), `files` (uploads,
file commands, the job), `keys` (the app-key flow); `common` is what they share, `api` puts them together behind
the key check.
"""

from marlin_aio.service.octoprint.api import OctoPrintApi
from marlin_aio.service.octoprint.server import OCTOPRINT_VERSION

__all__ = ["OCTOPRINT_VERSION", "OctoPrintApi"]

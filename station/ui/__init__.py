"""The operator station in the browser: `station ui` serves the operator and review screens.

Layout: `app.py` builds the web app (routes only), `controller.py` holds the station's live
state and the one-run-per-fixture rule, `hub.py` pushes events to every open page (SSE),
`runner_adapter.py` is the only module that knows the end-of-line engine (station/uut.py),
`history.py` answers the review screen, `auth.py` checks the engineer's password.
"""

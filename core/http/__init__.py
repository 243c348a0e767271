"""The gateway's read-only HTTP status server: API, Prometheus metrics, events, live page.

See :mod:`fieldgate.http.service` for the endpoints and docs/observability.md.
"""

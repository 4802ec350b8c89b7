"""The API's HTTP plumbing, beside the domain routes: the request guard in front of the routes
(:mod:`~daemon.api.http.guard`), the server's bounds on clients (:mod:`~daemon.api.http.server`),
``OPTIONS`` and the 405's ``Allow`` (:mod:`~daemon.api.http.methods`), the latency middleware
(:mod:`~daemon.api.http.latency`), download headers (:mod:`~daemon.api.http.downloads`), the
streaming multipart reader (:mod:`~daemon.api.http.multipart`) and the bounds of CPU-heavy
request work (:mod:`~daemon.api.http.offload`). This package module re-exports nothing."""

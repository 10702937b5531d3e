"""What a Dask worker is asked before any log is sent to it (shipped by value: it must run where slamobs
cannot even be imported, to say so)."""


def probe() -> dict:
    """This worker's slamobs version and code hash, or why slamobs cannot be imported here."""
    import socket
    import sys

    try:
        from slamobs.pipeline.version import __version__
        from slamobs.pipeline.batch.identity import code_hash

        return {
            "ok": True,
            "version": __version__,
            "code": code_hash(),
            "host": socket.gethostname(),
            "python": sys.executable,
        }
    except Exception as err:  # noqa: BLE001 - whatever it is, it is the answer
        text = " ".join(str(err).split())  # errors.one_line, without importing slamobs, which may be what failed
        return {
            "ok": False,
            "error": f"{type(err).__name__}: {text}",
            "host": socket.gethostname(),
            "python": sys.executable,
        }

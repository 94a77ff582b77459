"""Certificates for the tests' TLS servers (an engine over TCP, an HTTPS server standing in for
GitHub behind a TLS-intercepting proxy), made by openssl: a CA of the test's own, which no system
store holds."""

from __future__ import annotations

import shutil
import ssl
import subprocess
from pathlib import Path


def make_certificates(home: Path, client: bool = True) -> ssl.SSLContext:
    """A CA, the engine's certificate for 127.0.0.1 and a client's in HOME/client (ca.pem,
    cert.pem, key.pem: what DOCKER_CERT_PATH names, as a docker:dind service makes them), by
    openssl; the engine's server context, which asks for a client certificate of that CA.
    Without CLIENT: HOME/client holds only ca.pem, and the engine asks for no certificate."""

    def openssl(*args: str) -> None:
        subprocess.run(["openssl", *args], cwd=home, capture_output=True, check=True)

    # P-256 keys: an RSA key took openssl about 0.2 s of CPU, three per call, and the suite
    # makes certificates for a dozen servers; Go's TLS (the engine, the CLI) and Python's take both.
    newkey = ("-newkey", "ec", "-pkeyopt", "ec_paramgen_curve:prime256v1")

    (home / "client").mkdir()
    openssl("req", "-x509", *newkey, "-nodes", "-keyout", "ca-key.pem", "-out", "ca.pem",
            "-days", "1", "-subj", "/CN=espdock test CA")  # fmt: skip
    for name, usage, key in (("server", "serverAuth", "server-key.pem"), ("client", "clientAuth", "client/key.pem")):
        (home / f"{name}.ext").write_text(f"extendedKeyUsage={usage}\nsubjectAltName=IP:127.0.0.1\n")
        openssl("req", *newkey, "-nodes", "-keyout", key, "-out", f"{name}.csr", "-subj", f"/CN={name}")
        cert = "server.pem" if name == "server" else "client/cert.pem"
        openssl("x509", "-req", "-in", f"{name}.csr", "-CA", "ca.pem", "-CAkey", "ca-key.pem", "-CAcreateserial",
                "-out", cert, "-days", "1", "-extfile", f"{name}.ext")  # fmt: skip
    shutil.copy(home / "ca.pem", home / "client/ca.pem")
    context = ssl.SSLContext(ssl.PROTOCOL_TLS_SERVER)
    context.load_cert_chain(home / "server.pem", home / "server-key.pem")
    context.load_verify_locations(home / "ca.pem")
    context.verify_mode = ssl.CERT_REQUIRED
    if not client:
        (home / "client/cert.pem").unlink()
        (home / "client/key.pem").unlink()
        context.verify_mode = ssl.CERT_NONE
    return context

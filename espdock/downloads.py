"""How espdock's own downloads on this machine (rosdep's database, uv's locks) reach out: the
CAs they trust, with the extra one a TLS-intercepting proxy needs (espdock's ca_bundle), and what
to do when a proxy or a certificate stood in the way."""

from __future__ import annotations

import contextlib
import os
import re
from collections.abc import Iterator, Mapping
from pathlib import Path
from urllib.parse import urlsplit

from espdock import scratch


def uv_env(tmp: Path, ca_bundle: Path | None = None) -> dict[str, str]:
    """The environment uv runs in: this one, with TMP (removed afterwards) as its temp dir. uv
    leaves a lock file in the temp dir for every setuptools source tree it builds (a pip key's
    sdist), about one per `espdock lock` here. CA_BUNDLE: the extra CA bundle (espdock's
    ca_bundle, else pip's configured cert), which uv reads from no pip.conf: with the system's
    CAs (or those of the user's own SSL_CERT_FILE), its SSL_CERT_FILE."""
    env = {**os.environ, "TMPDIR": str(tmp)}
    if ca_bundle is not None:
        env["SSL_CERT_FILE"] = str(with_system_cas(ca_bundle, tmp, env.get("SSL_CERT_FILE")))
    return env


def with_system_cas(ca_bundle: Path, tmp: Path, own: str | None = None) -> Path:
    """A file in TMP holding the CAs of OWN (the user's SSL_CERT_FILE), else the system's, and
    CA_BUNDLE's: SSL_CERT_FILE replaces the former. An SSL_CERT_FILE naming the system's bundle
    (CI images set one) left the proxy's CA out."""
    import ssl

    paths = ssl.get_default_verify_paths()
    found = (own, paths.cafile, paths.openssl_cafile, "/etc/ssl/certs/ca-certificates.crt")
    base = next((Path(p) for p in found if p and Path(p).is_file()), None)
    combined = tmp / "espdock-ca.pem"
    combined.write_bytes((base.read_bytes() + b"\n" if base else b"") + ca_bundle.read_bytes())
    return combined


@contextlib.contextmanager
def cert_file(ca_bundle: Path | None) -> Iterator[None]:
    """SSL_CERT_FILE, for this process's default TLS contexts (rosdep's urlopen), set to the CAs it
    names (else the system's) and CA_BUNDLE's while the block runs."""
    if ca_bundle is None:
        yield
        return
    before = os.environ.get("SSL_CERT_FILE")
    with scratch.scratch_dir("espdock-ca-") as tmp:
        os.environ["SSL_CERT_FILE"] = str(with_system_cas(ca_bundle, tmp, before))
        try:
            yield
        finally:
            if before is None:
                os.environ.pop("SSL_CERT_FILE", None)
            else:
                os.environ["SSL_CERT_FILE"] = before


def network_hint(error: str, env: Mapping[str, str], who: str, then: str) -> str | None:
    """What to do about ERROR (WHO's words for a download that failed: rosdep's, uv's) where it
    names a certificate no CA here vouches for, or where a proxy of ENV's stood between; THEN: what
    to run once it is fixed."""
    if "CERTIFICATE_VERIFY_FAILED" in error or "UnknownIssuer" in error:
        return (
            "This machine does not trust the server's certificate: behind a TLS-intercepting proxy, give its CA "
            f"(ca_bundle in espdock.toml, or ESPDOCK_CA_BUNDLE), then {then}."
        )
    proxy = next((env[name] for name in ("HTTPS_PROXY", "https_proxy", "ALL_PROXY", "all_proxy") if env.get(name)), "")
    if proxy and re.search(r"(?i)refused|timed out|unreachable|tunnel|proxy|\b40[37]\b", error):
        where = urlsplit(proxy if "://" in proxy else f"http://{proxy}").netloc.rpartition("@")[2]  # no password
        return (
            f"{who} went through the proxy at {where}: check that it is up and lets its downloads through, then {then}."
        )
    return None

"""``followbot certs DIR``: a certificate authority and one certificate per identity.

Writes, for a secure deployment (docs/compose.md, "Secure deployment"):

    DIR/ca.pem               the CA certificate every process trusts
    DIR/ca.key               the CA's private key: keep it off the robot (needed only to sign more)
    DIR/<identity>.pem       the identity's certificate; its common name is the identity
    DIR/<identity>.key       its private key
    DIR/<identity>.password  its Zenoh password (user = the identity)
    DIR/users.txt            the router's user:password dictionary

Keys, passwords and users.txt are written with mode 0600. The router's certificate also names
the addresses the other machines reach it at (``--router-host``): they check it when they
connect. The identities are those of a compose file (``--compose``: one per process, plus
``operator`` for ``followbot target``) or named with ``--identity``.

When DIR already has a CA (ca.pem and ca.key), new identities are signed by it and added to
users.txt, so one more console or service can join a running deployment (the router reads
users.txt when it starts: restart it). A file that exists is never replaced unless --force,
which also makes a new CA.
"""

from __future__ import annotations

import argparse
import datetime
import ipaddress
import os
import secrets
import sys
from collections.abc import Iterable
from pathlib import Path

__all__ = ["DEFAULT_IDENTITIES", "CertError", "main", "make_certs"]

#: The identities of compose/split_secure.yaml, for `followbot certs DIR` with no --compose.
DEFAULT_IDENTITIES = (
    "router",
    "sim",
    "laser_legs",
    "tracker",
    "controller",
    "vision_verify",
    "operator",
)
_ROUTER_NAMES = ("localhost", "127.0.0.1")


class CertError(ValueError):
    """Certificates that cannot be written (files already there, a bad name or address)."""


def make_certs(
    folder: Path,
    identities: Iterable[str],
    *,
    router: str = "router",
    router_hosts: Iterable[str] = (),
    days: int = 825,
    force: bool = False,
) -> list[Path]:
    """Write a CA and a certificate, key and password per identity into ``folder``; return
    the files written. ``router`` names the identity that listens (it gets server names:
    localhost, 127.0.0.1 and ``router_hosts``). A CA already in ``folder`` signs the new
    identities (unless ``force``). Refuses to overwrite a file unless ``force``."""
    from cryptography import x509
    from cryptography.hazmat.primitives import hashes, serialization
    from cryptography.hazmat.primitives.asymmetric import ec
    from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

    from followbot.services.runtime.security import check_identity

    names = list(dict.fromkeys(identities))
    if not names:
        raise CertError("no identity to make a certificate for")
    for name in names:
        try:
            check_identity(name)
        except ValueError as exc:
            raise CertError(str(exc)) from None
    if days < 1:
        raise CertError(f"--days must be at least 1, got {days}")
    sans: list[x509.GeneralName] = []
    for host in dict.fromkeys([*_ROUTER_NAMES, *router_hosts]):
        try:
            sans.append(x509.IPAddress(ipaddress.ip_address(host)))
        except ValueError:
            if not host or any(c.isspace() or c in "/:" for c in host):
                raise CertError(
                    f"--router-host {host!r} is neither an IP address nor a host name"
                ) from None
            sans.append(x509.DNSName(host))

    ca_files = [folder / "ca.pem", folder / "ca.key"]
    reuse_ca = all(p.is_file() for p in ca_files) and not force
    paths = [] if reuse_ca else list(ca_files)
    for name in names:
        paths += [folder / f"{name}.pem", folder / f"{name}.key", folder / f"{name}.password"]
    there = [p for p in paths if p.exists()]
    if there and not force:
        raise CertError(
            f"{len(there)} file(s) already exist, e.g. {there[0]}; pass --force to replace them "
            "(with a new CA: every process then needs the new files)"
        )
    folder.mkdir(parents=True, exist_ok=True)

    now = datetime.datetime.now(datetime.UTC)
    not_before = now - datetime.timedelta(minutes=5)  # clocks of two machines differ a little
    not_after = now + datetime.timedelta(days=days)

    def new_key():
        return ec.generate_private_key(ec.SECP256R1())

    def subject(cn: str) -> x509.Name:
        return x509.Name(
            [
                x509.NameAttribute(NameOID.ORGANIZATION_NAME, "followbot"),
                x509.NameAttribute(NameOID.COMMON_NAME, cn),
            ]
        )

    if reuse_ca:  # add identities to an existing deployment, signed by its CA
        try:
            ca_cert = x509.load_pem_x509_certificate((folder / "ca.pem").read_bytes())
            ca_key = serialization.load_pem_private_key((folder / "ca.key").read_bytes(), None)
        except ValueError as exc:
            raise CertError(f"cannot read the CA in {folder}: {exc}") from None
        ca_name = ca_cert.subject
        not_after = min(not_after, ca_cert.not_valid_after_utc)
    else:
        ca_key = new_key()
        ca_name = subject("followbot CA")
        ca_usage = x509.KeyUsage(
            digital_signature=False, content_commitment=False, key_encipherment=False,
            data_encipherment=False, key_agreement=False, key_cert_sign=True, crl_sign=True,
            encipher_only=False, decipher_only=False,
        )  # fmt: skip
        ca_cert = (
            x509.CertificateBuilder()
            .subject_name(ca_name)
            .issuer_name(ca_name)
            .public_key(ca_key.public_key())
            .serial_number(x509.random_serial_number())
            .not_valid_before(not_before)
            .not_valid_after(not_after)
            .add_extension(x509.BasicConstraints(ca=True, path_length=0), critical=True)
            .add_extension(ca_usage, critical=True)
            .add_extension(x509.SubjectKeyIdentifier.from_public_key(ca_key.public_key()), False)
            .sign(ca_key, hashes.SHA256())
        )

    def pem_key(key) -> bytes:
        return key.private_bytes(
            serialization.Encoding.PEM,
            serialization.PrivateFormat.PKCS8,
            serialization.NoEncryption(),
        )

    written: list[Path] = []

    def write(name: str, data: bytes, secret: bool) -> None:
        path = folder / name
        # Created with the final mode, so a secret is never readable by others, not even
        # for a moment; an existing file (--force) is truncated and its mode set again.
        fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600 if secret else 0o644)
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
        os.chmod(path, 0o600 if secret else 0o644)
        written.append(path)

    if not reuse_ca:
        write("ca.pem", ca_cert.public_bytes(serialization.Encoding.PEM), secret=False)
        write("ca.key", pem_key(ca_key), secret=True)
    # users.txt keeps the users of identities made before with this CA
    users: dict[str, str] = {}
    if reuse_ca and (folder / "users.txt").is_file():
        for line in (folder / "users.txt").read_text().splitlines():
            user, sep, password = line.partition(":")
            if sep:
                users[user] = password
    for name in names:
        key = new_key()
        usage = [ExtendedKeyUsageOID.CLIENT_AUTH]
        builder = (
            x509.CertificateBuilder()
            .subject_name(subject(name))
            .issuer_name(ca_name)
            .public_key(key.public_key())
            .serial_number(x509.random_serial_number())
            .not_valid_before(not_before)
            .not_valid_after(not_after)
            .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
            .add_extension(
                x509.AuthorityKeyIdentifier.from_issuer_public_key(ca_key.public_key()), False
            )
        )
        if name == router:
            usage.append(ExtendedKeyUsageOID.SERVER_AUTH)
            builder = builder.add_extension(x509.SubjectAlternativeName(sans), critical=False)
        cert = builder.add_extension(x509.ExtendedKeyUsage(usage), critical=False).sign(
            ca_key, hashes.SHA256()
        )
        write(f"{name}.pem", cert.public_bytes(serialization.Encoding.PEM), secret=False)
        write(f"{name}.key", pem_key(key), secret=True)
        password = secrets.token_urlsafe(24)
        write(f"{name}.password", (password + "\n").encode(), secret=True)
        users[name] = password
    write("users.txt", "".join(f"{u}:{p}\n" for u, p in users.items()).encode(), secret=True)
    return written


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(
        prog="followbot certs",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog="examples:\n"
        "  followbot certs certs --compose compose/split_secure.yaml --router-host 192.168.1.10\n"
        "  followbot certs certs --identity router --identity operator --force",
    )
    p.add_argument("folder", type=Path, help="where to write the files (made if missing)")
    p.add_argument(
        "--compose",
        metavar="FILE",
        help="make the identities of this compose file (each process, and its security "
        "section's extra identities, e.g. operator)",
    )
    p.add_argument(
        "--identity",
        action="append",
        default=[],
        metavar="NAME",
        help="an identity to make a certificate for (repeatable); without --compose or "
        f"--identity: {', '.join(DEFAULT_IDENTITIES)}",
    )
    p.add_argument(
        "--router-host",
        action="append",
        default=[],
        metavar="HOST",
        help="an IP address or host name the router is reached at, written into the router's "
        "certificate (repeatable; localhost and 127.0.0.1 are always in it)",
    )
    p.add_argument(
        "--router",
        default=None,
        metavar="NAME",
        help="the identity that listens as the Zenoh router (default: the compose file's "
        "router process, or 'router')",
    )
    p.add_argument("--days", type=int, default=825, help="validity in days (825)")
    p.add_argument("--force", action="store_true", help="replace files that already exist")
    args = p.parse_args(argv)

    identities = list(args.identity)
    router = args.router
    if args.compose:
        from followbot.services.runtime.compose import ComposeError, load_compose
        from followbot.services.runtime.security import compose_identities

        try:
            compose = load_compose(args.compose)
            found, compose_router = compose_identities(compose)
        except (ComposeError, ValueError) as exc:
            print(f"followbot certs: {exc}", file=sys.stderr)
            return 2
        identities += list(found)
        router = router or compose_router
    if not identities:
        identities = list(DEFAULT_IDENTITIES)
    router = router or "router"
    has_ca = (args.folder / "ca.pem").is_file() and (args.folder / "ca.key").is_file()
    if router not in identities and (args.force or not has_ca):
        identities.insert(0, router)  # a new CA needs a router to be of any use
    try:
        written = make_certs(
            args.folder,
            identities,
            router=router,
            router_hosts=args.router_host,
            days=args.days,
            force=args.force,
        )
    except CertError as exc:
        print(f"followbot certs: {exc}", file=sys.stderr)
        return 1
    for path in written:
        print(f"wrote {path}")
    names = ", ".join(f"{n} (router)" if n == router else n for n in dict.fromkeys(identities))
    print(f"identities: {names}; keep ca.key off the robot")
    return 0

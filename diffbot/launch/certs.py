"""``diffbot certs``: a test CA and certificates for a simulation over (mutual) TLS.

    diffbot certs --out ~/diffbot-certs --router 198.51.100.1 [--router router.lan]

writes, with the ``openssl`` command:

    ca.pem, ca-key.pem            the CA (keep ca-key.pem off the robots)
    router.pem, router-key.pem    the router's: its subjectAltName lists every --router
                                  address or name (clients dialling an IP check the IP SAN)
    <role>.pem, <role>-key.pem    one client certificate per role, common name = role:
                                  plant, node, recorder, view, bridge (--roles to choose)

The shipped configs (``diffbot/launch/configs/*_tls.json5``) find them as
``${DIFFBOT_CERTS}/<role>.pem``, and the shipped router's access control admits each role
by that common name. Copy ``ca.pem`` and a role's two files to the machine that runs it.
This is a test CA (EC P-256, valid ``--days``): fine for a lab, not a production PKI.
"""
from __future__ import annotations

import ipaddress
import os
import shutil
import subprocess
import sys

from bus.cliargs import ArgumentParser

#: client roles and who uses each (the shipped ACL admits exactly these common names)
ROLES = {
    "plant": "diffbot plant",
    "node": "controllers, fmu-node (any process that commands a robot)",
    "recorder": "diffbot record, topics, echo (listen only)",
    "view": "diffbot view (Foxglove; listens, teleop commands)",
    "bridge": "diffbot ros2 (listens; commands from ROS 2)",
}


def san(names: list[str]) -> str:
    """subjectAltName for ``names``: IP: for addresses, DNS: for host names."""
    out = []
    for n in names:
        try:
            out.append(f"IP:{ipaddress.ip_address(n)}")
        except ValueError:
            out.append(f"DNS:{n}")
    return ",".join(out)


def _openssl(*args: str, cwd: str) -> None:
    r = subprocess.run(["openssl", *args], cwd=cwd, capture_output=True, text=True)
    if r.returncode:
        raise RuntimeError(f"openssl {args[0]} failed: {r.stderr.strip()}")


def _leaf(out: str, name: str, subject_alt: str, usage: str, days: int) -> None:
    _openssl("req", "-new", "-newkey", "ec", "-pkeyopt", "ec_paramgen_curve:prime256v1",
             "-nodes", "-keyout", f"{name}-key.pem", "-out", f"{name}.csr",
             "-subj", f"/CN={name}", cwd=out)
    ext = os.path.join(out, f"{name}.ext")
    with open(ext, "w") as f:
        f.write(f"subjectAltName={subject_alt}\nbasicConstraints=critical,CA:FALSE\n"
                f"keyUsage=critical,digitalSignature\nextendedKeyUsage={usage}\n")
    _openssl("x509", "-req", "-in", f"{name}.csr", "-CA", "ca.pem", "-CAkey", "ca-key.pem",
             "-CAcreateserial", "-days", str(days), "-extfile", ext, "-out", f"{name}.pem",
             cwd=out)
    for tmp in (f"{name}.csr", f"{name}.ext"):
        os.remove(os.path.join(out, tmp))
    os.chmod(os.path.join(out, f"{name}-key.pem"), 0o600)


def make_certs(out: str, routers: list[str], roles: list[str] | None = None,
               days: int = 365) -> dict[str, str]:
    """CA, router and role certificates in ``out``; name -> certificate path."""
    os.makedirs(out, exist_ok=True)
    _openssl("req", "-x509", "-new", "-newkey", "ec", "-pkeyopt",
             "ec_paramgen_curve:prime256v1", "-nodes", "-days", str(days),
             "-subj", "/CN=diffbot test CA", "-addext", "basicConstraints=critical,CA:TRUE",
             "-addext", "keyUsage=critical,keyCertSign,cRLSign",
             "-keyout", "ca-key.pem", "-out", "ca.pem", cwd=out)
    os.chmod(os.path.join(out, "ca-key.pem"), 0o600)
    _leaf(out, "router", san(routers), "serverAuth,clientAuth", days)
    written = {"ca": os.path.join(out, "ca.pem"), "router": os.path.join(out, "router.pem")}
    for role in roles or list(ROLES):
        _leaf(out, role, f"DNS:{role}", "clientAuth", days)
        written[role] = os.path.join(out, f"{role}.pem")
    srl = os.path.join(out, "ca.srl")
    if os.path.exists(srl):
        os.remove(srl)
    return written


def main(argv: list[str] | None = None) -> int:
    p = ArgumentParser(prog="diffbot certs", description=__doc__.split("\n\n")[0])
    p.add_argument("--out", required=True, help="directory for the certificates and keys")
    p.add_argument("--router", action="append", metavar="ADDR",
                   help="an address or host name clients dial the router at (repeatable; "
                        "default localhost and 127.0.0.1)")
    p.add_argument("--roles", default=",".join(ROLES),
                   help=f"client certificates to make (default {','.join(ROLES)})")
    p.add_argument("--days", type=int, default=365, help="validity (default 365)")
    args = p.parse_args(argv)
    roles = [r for r in args.roles.split(",") if r]
    unknown = [r for r in roles if r not in ROLES]
    if unknown:
        p.error(f"unknown role(s) {', '.join(unknown)}: the shipped access control admits "
                f"{', '.join(ROLES)}")
    if shutil.which("openssl") is None:
        print("diffbot certs: needs the `openssl` command (apt install openssl)", file=sys.stderr)
        return 2
    routers = args.router or ["localhost", "127.0.0.1"]
    try:
        written = make_certs(args.out, routers, roles, args.days)
    except (OSError, RuntimeError) as exc:
        print(f"diffbot certs: {exc}", file=sys.stderr)
        return 2
    out = os.path.abspath(args.out)
    print(f"CA and certificates in {out} (router: {san(routers)}):")
    for name, path in written.items():
        print(f"  {name:9s} {os.path.basename(path)}"
              + (f"  {ROLES[name]}" if name in ROLES else ""))
    print(f"Point the shipped configs at them on each machine:\n  export DIFFBOT_CERTS={out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

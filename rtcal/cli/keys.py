"""``rtcal key generate``: the laboratory's Ed25519 key pair that signs its runs (rtcal/run/signing.py)."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from rtcal.cli.common import EXIT_OK


def cmd_key(args: argparse.Namespace) -> int:
    """A new key pair under --out: the private key (mode 0600, never printed) and the public key."""
    from rtcal.run.signing import LAB_KEY_ENV, LAB_PUBLIC_KEYS_ENV, generate_key_pair

    private, public, fingerprint = generate_key_pair(Path(args.out), args.signer)
    print(f"private key: {private} (mode 0600: keep it outside every run folder, readable by the lab's rigs only)")
    print(f"public key:  {public} (give it to every computer that checks runs)")
    print(f"fingerprint: {fingerprint} (certificates name the key by it)")
    print(f"sign runs with:  export {LAB_KEY_ENV}={private}")
    print(f"check runs with: export {LAB_PUBLIC_KEYS_ENV}={public}")
    return EXIT_OK


def add_key(sub: Any) -> None:
    key = sub.add_parser("key", help="the laboratory's signing key: runs signed with it, checked against its public key")
    key_sub = key.add_subparsers(dest="key_command", required=True)
    gen = key_sub.add_parser("generate", help="make an Ed25519 key pair (lab_ed25519.key, mode 0600, and lab_ed25519.pub) "
                                              "in a folder; an existing key is never replaced")
    gen.add_argument("--out", required=True, metavar="DIR", help="the folder for the key pair (created owner-only if new; "
                                                                 "outside every run folder)")
    gen.add_argument("--signer", required=True, help="who the key signs for, as certificates name it (e.g. the "
                                                     "laboratory and its accreditation)")
    gen.set_defaults(func=cmd_key)

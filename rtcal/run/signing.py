"""The laboratory's signature on what a run hands over: Ed25519 keys (``cryptography``), the signed
document, and the keys a lab configures.

Digests (rtcal/run/integrity.py) catch an accident; anyone who can write a run folder can recompute
them. A run written with the lab's private key configured carries ``signature.json``: an Ed25519
signature over the SHA-256 of results.json as written (which records the digests of the store's
readings, events and procedure and of every deliverable), those digests again, who signed and the
key's fingerprint. Forging a run then needs the private key, which never lies in a run folder.

Configuration is by environment variables (no configuration file):

- ``RTCAL_LAB_KEY``: the path of the lab's private key (made by ``rtcal key generate``; the file
  readable by its owner only, outside every run folder). ``rtcal run`` and ``rtcal resume`` sign with
  it; unset, a run is written unsigned and says so.
- ``RTCAL_LAB_PUBLIC_KEYS``: the lab's public key files (``os.pathsep``-separated; a folder means every
  ``*.pub`` in it). ``verify``, ``evaluate``, ``compensate`` and ``catalog add`` check a run's signature
  against them (the public half of ``RTCAL_LAB_KEY`` counts too) and refuse an unsigned run or one
  signed by another key. Neither set: nothing can be checked, a run is marked unsigned.

A key file is text: a line ``Signer: NAME`` (who the key signs for, as certificates name it) before
the PEM block (PKCS#8 private key, or SubjectPublicKeyInfo public key). The fingerprint is
``SHA256:`` and the unpadded base64 of the SHA-256 of the raw 32-byte public key (OpenSSH's form)."""

from __future__ import annotations

import base64
import hashlib
import json
import os
import stat
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping

from rtcal.errors import UserError

LAB_KEY_ENV = "RTCAL_LAB_KEY"
LAB_PUBLIC_KEYS_ENV = "RTCAL_LAB_PUBLIC_KEYS"
SIGNATURE_FILENAME = "signature.json"
FORMAT = "rtcal-run-signature/1"
PRIVATE_NAME, PUBLIC_NAME = "lab_ed25519.key", "lab_ed25519.pub"
MAX_KEY_FILE_BYTES = 16_384
MAX_PUBLIC_KEYS = 100
MAX_SIGNATURE_BYTES = 4_000_000  # 10 000 deliverables' digests at most (results.json's own bound)
MAX_SIGNER_CHARS = 200


class KeyConfigError(UserError):
    """A lab key that is configured but cannot be used (exit 2): the message names the file and why."""


@dataclass(frozen=True)
class PublicKey:
    signer: str
    fingerprint: str
    key: Any  # cryptography's Ed25519PublicKey


@dataclass(frozen=True)
class LabKey:
    """The private key a run is signed with (never printed, never written into a run)."""

    signer: str
    fingerprint: str
    key: Any  # cryptography's Ed25519PrivateKey
    path: Path

    @property
    def public(self) -> PublicKey:
        return PublicKey(self.signer, self.fingerprint, self.key.public_key())


def fingerprint(public_key: Any) -> str:
    """``SHA256:`` + unpadded base64 of the SHA-256 of the raw public key (as OpenSSH shows keys)."""
    from cryptography.hazmat.primitives.serialization import Encoding, PublicFormat

    raw = public_key.public_bytes(Encoding.Raw, PublicFormat.Raw)
    return "SHA256:" + base64.b64encode(hashlib.sha256(raw).digest()).decode("ascii").rstrip("=")


def check_signer(signer: str) -> str:
    """Who a key signs for: 1 to 200 printable characters on one line (it goes onto certificates)."""
    import unicodedata

    signer = signer.strip()
    if not signer or len(signer) > MAX_SIGNER_CHARS:
        raise KeyConfigError(f"a signer is 1 to {MAX_SIGNER_CHARS} characters (the laboratory, as its certificates name it)")
    if any(unicodedata.category(c) in ("Cc", "Cf", "Cs", "Co") for c in signer):
        raise KeyConfigError("no control or invisible formatting characters in a signer")
    return signer


def _key_text(kind: str, signer: str, pem: bytes, fp: str) -> bytes:
    head = (f"rtcal laboratory {kind} key (Ed25519)\nSigner: {signer}\nFingerprint: {fp}\n")
    return head.encode("utf-8") + pem


def generate_key_pair(folder: Path, signer: str) -> tuple[Path, Path, str]:
    """A new key pair in ``folder`` (created owner-only if new): the private key file with mode 0600,
    created exclusively (an existing key is never replaced), and the public key beside it."""
    from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey
    from cryptography.hazmat.primitives.serialization import Encoding, NoEncryption, PrivateFormat, PublicFormat

    signer = check_signer(signer)
    folder = Path(folder)
    if os.path.lexists(folder / "run.sqlite"):
        raise KeyConfigError(f"--out {folder}: a run folder; a lab key lives outside every run folder")
    try:
        folder.mkdir(mode=0o700, parents=True, exist_ok=True)
    except OSError as exc:
        raise KeyConfigError(f"--out {folder}: cannot create the folder ({exc.strerror or exc})") from None
    private_path, public_path = folder / PRIVATE_NAME, folder / PUBLIC_NAME
    for path in (private_path, public_path):
        if os.path.lexists(path):
            raise KeyConfigError(f"{path} exists: rtcal never replaces a key (choose another --out)")
    key = Ed25519PrivateKey.generate()
    fp = fingerprint(key.public_key())
    private_pem = key.private_bytes(Encoding.PEM, PrivateFormat.PKCS8, NoEncryption())
    public_pem = key.public_key().public_bytes(Encoding.PEM, PublicFormat.SubjectPublicKeyInfo)
    try:
        fd = os.open(private_path, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW, 0o600)
        with os.fdopen(fd, "wb") as fh:
            fh.write(_key_text("private", signer, private_pem, fp))
        os.chmod(private_path, 0o600)  # whatever the umask
        fd = os.open(public_path, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW, 0o644)
        with os.fdopen(fd, "wb") as fh:
            fh.write(_key_text("public", signer, public_pem, fp))
    except OSError as exc:
        raise KeyConfigError(f"{folder}: cannot write the key pair ({exc.strerror or exc})") from None
    return private_path, public_path, fp


def _read_key_file(path: Path, what: str) -> tuple[str, bytes]:
    """(signer, PEM block) of a key file rtcal wrote; KeyConfigError naming the file otherwise."""
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK)
    except OSError as exc:
        raise KeyConfigError(f"{what} {path}: cannot read ({exc.strerror or exc})") from None
    with os.fdopen(fd, "rb") as fh:
        st = os.fstat(fh.fileno())
        if not stat.S_ISREG(st.st_mode):
            raise KeyConfigError(f"{what} {path}: not a regular file")
        if what == LAB_KEY_ENV and st.st_mode & 0o077:
            raise KeyConfigError(f"{what} {path}: its permissions {stat.S_IMODE(st.st_mode):04o} let others read it; only "
                                 f"its owner may (chmod 600 {path})")
        data = fh.read(MAX_KEY_FILE_BYTES + 1)
    if len(data) > MAX_KEY_FILE_BYTES:
        raise KeyConfigError(f"{what} {path}: larger than a key file")
    text = data.decode("utf-8", errors="replace")
    signer = next((line.partition(":")[2].strip() for line in text.splitlines() if line.startswith("Signer:")), "")
    begin = data.find(b"-----BEGIN ")
    if not signer or begin < 0:
        raise KeyConfigError(f"{what} {path}: not a key file `rtcal key generate` wrote (a `Signer:` line, then a PEM key)")
    try:
        return check_signer(signer), data[begin:]
    except KeyConfigError as exc:
        raise KeyConfigError(f"{what} {path}: {exc}") from None


def load_lab_key(env: Mapping[str, str] | None = None, run_dir: Path | None = None) -> LabKey | None:
    """The private key ``RTCAL_LAB_KEY`` names (None: unset): owner-only, Ed25519, and not inside
    ``run_dir`` (a key beside the run it signs proves nothing)."""
    from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey
    from cryptography.hazmat.primitives.serialization import load_pem_private_key

    env = os.environ if env is None else env
    text = env.get(LAB_KEY_ENV, "")
    if not text:
        return None
    path = Path(text).expanduser()
    if run_dir is not None:
        try:
            inside = path.resolve().is_relative_to(Path(run_dir).resolve())
        except OSError:
            inside = False
        if inside:
            raise KeyConfigError(f"{LAB_KEY_ENV} {path}: lies inside the run folder {run_dir}; keep the lab key outside "
                                 "every run folder")
    signer, pem = _read_key_file(path, LAB_KEY_ENV)
    try:
        key = load_pem_private_key(pem, password=None)
    except (ValueError, TypeError) as exc:
        raise KeyConfigError(f"{LAB_KEY_ENV} {path}: not a private key rtcal can use ({str(exc)[:120]})") from None
    if not isinstance(key, Ed25519PrivateKey):
        raise KeyConfigError(f"{LAB_KEY_ENV} {path}: not an Ed25519 key (`rtcal key generate` makes one)")
    return LabKey(signer, fingerprint(key.public_key()), key, path)


def _public_key_files(text: str) -> list[Path]:
    found: list[Path] = []
    for part in (p for p in text.split(os.pathsep) if p):
        path = Path(part).expanduser()
        if path.is_dir():
            found += sorted(path.glob("*.pub"))
        else:
            found.append(path)
    if len(found) > MAX_PUBLIC_KEYS:
        raise KeyConfigError(f"{LAB_PUBLIC_KEYS_ENV}: {len(found)} key files (at most {MAX_PUBLIC_KEYS})")
    return found


def trusted_keys(env: Mapping[str, str] | None = None) -> dict[str, PublicKey]:
    """The lab's public keys by fingerprint: ``RTCAL_LAB_PUBLIC_KEYS`` and the public half of
    ``RTCAL_LAB_KEY``. Empty: no key is configured (runs cannot be checked, and are marked unsigned)."""
    from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PublicKey
    from cryptography.hazmat.primitives.serialization import load_pem_public_key

    env = os.environ if env is None else env
    keys: dict[str, PublicKey] = {}
    for path in _public_key_files(env.get(LAB_PUBLIC_KEYS_ENV, "")):
        signer, pem = _read_key_file(path, LAB_PUBLIC_KEYS_ENV)
        try:
            key = load_pem_public_key(pem)
        except (ValueError, TypeError) as exc:
            raise KeyConfigError(f"{LAB_PUBLIC_KEYS_ENV} {path}: not a public key ({str(exc)[:120]})") from None
        if not isinstance(key, Ed25519PublicKey):
            raise KeyConfigError(f"{LAB_PUBLIC_KEYS_ENV} {path}: not an Ed25519 key")
        keys[fingerprint(key)] = PublicKey(signer, fingerprint(key), key)
    own = load_lab_key(env)
    if own is not None:
        keys.setdefault(own.fingerprint, own.public)
    if env.get(LAB_PUBLIC_KEYS_ENV) and not keys:
        raise KeyConfigError(f"{LAB_PUBLIC_KEYS_ENV}={env[LAB_PUBLIC_KEYS_ENV][:200]}: names no key file")
    return keys


def payload(document: Mapping[str, Any]) -> bytes:
    """The bytes signed: the document without its ``signature``, as canonical JSON."""
    body = {k: v for k, v in document.items() if k != "signature"}
    return json.dumps(body, sort_keys=True, separators=(",", ":"), ensure_ascii=True, allow_nan=False).encode("ascii")


def signed_document(key: LabKey, results_sha256: str, digests: Mapping[str, Any], deliverables: Mapping[str, str],
                    signed_utc: str) -> dict[str, Any]:
    """signature.json's content: what is signed, and the signature over it (base64)."""
    doc: dict[str, Any] = {"format": FORMAT, "algorithm": "ed25519", "signer": key.signer,
                           "key_fingerprint": key.fingerprint, "signed_utc": signed_utc, "results_sha256": results_sha256,
                           "digests": dict(digests), "deliverables_sha256": dict(deliverables)}
    doc["signature"] = base64.b64encode(key.key.sign(payload(doc))).decode("ascii")
    return doc


def signature_valid(document: Mapping[str, Any], key: PublicKey) -> bool:
    """Whether ``document['signature']`` is ``key``'s over the rest of the document."""
    from cryptography.exceptions import InvalidSignature

    try:
        key.key.verify(base64.b64decode(str(document.get("signature", "")), validate=True), payload(document))
    except (InvalidSignature, ValueError, TypeError):
        return False
    return True

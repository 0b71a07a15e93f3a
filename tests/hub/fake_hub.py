"""A PROTOCOL FAKE of the Hugging Face Hub's write API, for the upload tests (docs/design.md 8).

This is not the Hub and not a mock of ``huggingface_hub``: it is a small HTTP server on 127.0.0.1
that answers the requests the real client library sends when it creates repos, commits files
(``preupload`` -> LFS ``batch`` + ``PUT`` -> NDJSON ``commit``), lists trees and refs, and creates or
deletes branches and tags.  The client under test is the unmodified ``huggingface_hub`` pointed at
it with ``HF_ENDPOINT``.

Storage is real git: each repo is a git repository at ``ROOT/{models,datasets}/ORG/NAME`` (the Hub
too stores repos as git), one git commit per Hub commit, one git tag per Hub tag, LFS objects stored
inline as plain blobs.  That layout is exactly what olah's offline mirror mode serves, so what the
fake received can be read back through a real Hub mirror (tests/hub/olah_server.py).

Simplifications, on purpose: every request must carry a bearer token, but any token is accepted;
``uploadMode`` is "lfs" for binary suffixes and files >= 10 MiB, "regular" otherwise; no pull
requests, Xet or multipart LFS; file downloads (``resolve``) as plain files with the git blob id as
their ETag, for the reads a push itself makes (``lhf push --source-repo``): the tests' other reads
go through olah, a real Hub mirror.
"""

from __future__ import annotations

import base64
import hashlib
import json
import os
import re
import subprocess
import threading
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from urllib.parse import parse_qs, unquote, urlsplit

LFS_SUFFIXES = (".parquet", ".safetensors", ".bin", ".png", ".pt", ".npz", ".arrow")
LFS_MIN_SIZE = 10 << 20
_API = re.compile(r"^/api/(models|datasets)/([^/]+)/([^/]+)(?:/(.*))?$")
_LFS_BATCH = re.compile(r"^/(?:(datasets)/)?([^/]+)/([^/]+?)\.git/info/lfs/objects/batch$")
_RESOLVE = re.compile(r"^/(?:(datasets)/)?([^/]+)/([^/]+)/resolve/([^/]+)/(.+)$")


class RawFile:
    """A file download's answer: its bytes and the headers ``hf_hub_download`` reads."""

    def __init__(self, data: bytes, headers: dict[str, str]):
        self.data, self.headers = data, headers


class HubProtocolError(Exception):
    def __init__(self, status: int, message: str, code: str | None = None):
        super().__init__(message)
        self.status, self.message, self.code = status, message, code


def _git(repo: Path, *args: str, input: bytes | None = None) -> str:
    out = subprocess.run(
        ["git", "-C", str(repo), "-c", "user.name=fake-hub", "-c", "user.email=fake@hub", *args],
        input=input,
        capture_output=True,
        check=True,
    )
    return out.stdout.decode()


class FakeHub:
    """The repo store and the protocol logic (``handle``); ``serve`` puts it on a loopback port."""

    def __init__(self, root: str | Path):
        self.root = Path(root)
        self.lfs = self.root / "_lfs"
        self.lfs.mkdir(parents=True, exist_ok=True)
        self.lock = threading.Lock()
        self.secret = os.urandom(16)
        self.requests: list[tuple[str, str, str]] = []  # (client ip, method, path)
        self.server: ThreadingHTTPServer | None = None
        #: Fault injection: reject this many upcoming commit requests with a 500 (the repo stays
        #: as it was, as on the Hub).
        self.fail_commits = 0
        #: Called when a commit request arrives, before it is applied or refused (e.g. to
        #: interrupt the client while it waits).
        self.on_commit = None

    # ------------------------------------------------------------------ store
    def repo_path(self, repo_type: str, org: str, name: str) -> Path:
        return self.root / repo_type / org / name

    def _repo(self, repo_type: str, org: str, name: str) -> Path:
        path = self.repo_path(repo_type, org, name)
        if not (path / ".git").exists():
            raise HubProtocolError(404, f"Repository {org}/{name} not found", "RepoNotFound")
        return path

    def _rev(self, repo: Path, revision: str) -> str:
        try:
            return _git(repo, "rev-parse", "--verify", f"{unquote(revision)}^{{commit}}").strip()
        except subprocess.CalledProcessError:
            raise HubProtocolError(
                404, f"Invalid rev id: {unquote(revision)}", "RevisionNotFound"
            ) from None

    def _refs(self, repo: Path, kind: str) -> list[dict]:
        out = _git(repo, "for-each-ref", "--format=%(refname) %(*objectname) %(objectname)", kind)
        refs = []
        for line in out.splitlines():
            parts = line.split()
            ref, target = parts[0], parts[1] if len(parts) == 3 else parts[-1]
            refs.append({"name": ref.split("/", 2)[2], "ref": ref, "targetCommit": target})
        return refs

    # ------------------------------------------------------------------ endpoints
    def create_repo(self, body: dict, base: str) -> tuple[int, dict]:
        repo_type = (body.get("type") or "model") + "s"
        org, name = body.get("organization"), body["name"]
        if not org:
            raise HubProtocolError(400, "the fake hub needs an organization (ORG/NAME)")
        path = self.repo_path(repo_type, org, name)
        prefix = "" if repo_type == "models" else f"{repo_type}/"
        url = f"{base}/{prefix}{org}/{name}"
        if (path / ".git").exists():
            return 409, {"error": "You already created this repo", "url": url}
        path.mkdir(parents=True)
        _git(path, "init", "-q", "-b", "main")
        # The Hub's first commit: a .gitattributes that routes binary files to LFS.
        (path / ".gitattributes").write_text(
            "".join(f"*{s} filter=lfs diff=lfs merge=lfs -text\n" for s in LFS_SUFFIXES)
        )
        _git(path, "add", "-A")
        _git(path, "commit", "-q", "-m", "initial commit")
        return 200, {"url": url, "name": f"{org}/{name}", "id": f"{org}/{name}"}

    def validate_yaml(self, body: dict) -> list[dict]:
        """The card metadata checks the Hub makes that our cards depend on: the front matter is a
        YAML mapping, and each dataset ``configs`` entry names its config and its data files."""
        import yaml

        m = re.match(r"^---\n(.*?)\n---", body.get("content", ""), re.S)
        if m is None:
            return []
        try:
            meta = yaml.safe_load(m[1])
        except yaml.YAMLError as exc:
            return [{"message": f"invalid YAML: {exc}"}]
        if not isinstance(meta, dict):
            return [{"message": "the metadata must be a YAML mapping"}]
        errors = []
        for c in meta.get("configs") or []:
            if not isinstance(c, dict) or not c.get("config_name") or not c.get("data_files"):
                errors.append({"message": f"configs entry {c!r} needs config_name and data_files"})
        return errors

    def preupload(self, repo: Path, revision: str, body: dict) -> dict:
        self._rev(repo, revision)
        files = []
        for f in body["files"]:
            sample = base64.b64decode(f["sample"])
            lfs = f["path"].endswith(LFS_SUFFIXES) or f["size"] >= LFS_MIN_SIZE or b"\0" in sample
            files.append(
                {
                    "path": f["path"],
                    "uploadMode": "lfs" if lfs else "regular",
                    "shouldIgnore": False,
                }
            )
        return {"files": files}

    def lfs_batch(self, body: dict, base: str) -> dict:
        if body.get("operation") != "upload":
            raise HubProtocolError(400, "the fake hub only takes LFS uploads")
        objects = []
        for o in body["objects"]:
            entry = {"oid": o["oid"], "size": o["size"], "authenticated": True}
            if not (self.lfs / o["oid"]).exists():
                # Like the Hub's presigned storage URLs: the upload URL carries its own signature
                # (the client sends no token there).
                sig = self._sign(o["oid"])
                entry["actions"] = {
                    "upload": {"href": f"{base}/_lfs/{o['oid']}?sig={sig}"},
                    "verify": {"href": f"{base}/_lfs/{o['oid']}/verify"},
                }
            objects.append(entry)
        return {"transfer": "basic", "objects": objects}

    def _sign(self, oid: str) -> str:
        return hashlib.sha256(self.secret + oid.encode()).hexdigest()[:32]

    def lfs_put(self, oid: str, data: bytes) -> None:
        if hashlib.sha256(data).hexdigest() != oid:
            raise HubProtocolError(400, f"LFS object {oid}: the content does not hash to its oid")
        (self.lfs / oid).write_bytes(data)

    def commit(self, repo: Path, revision: str, lines: list[dict], base: str, rid: str) -> dict:
        branch = unquote(revision)
        if f"refs/heads/{branch}" not in {r["ref"] for r in self._refs(repo, "refs/heads")}:
            raise HubProtocolError(404, f"Invalid rev id: {branch}", "RevisionNotFound")
        header = lines[0]
        if header.get("key") != "header":
            raise HubProtocolError(400, "the commit payload must start with a header line")
        # Validate everything before touching the work tree: a commit is all or nothing.
        writes, deletes = [], []
        for line in lines[1:]:
            key, v = line["key"], line["value"]
            if key == "file":
                writes.append((v["path"], base64.b64decode(v["content"])))
            elif key == "lfsFile":
                obj = self.lfs / v["oid"]
                if not obj.exists():
                    raise HubProtocolError(
                        400, f"LFS object {v['oid']} of {v['path']} was never uploaded"
                    )
                writes.append((v["path"], obj.read_bytes()))
            elif key in ("deletedFile", "deletedFolder"):
                deletes.append(v["path"])
            else:
                raise HubProtocolError(400, f"unknown commit operation {key!r}")
        for p, _ in writes:
            if p.startswith("/") or ".." in Path(p).parts or p.startswith(".git/"):
                raise HubProtocolError(400, f"invalid path in repo: {p!r}")
        _git(repo, "checkout", "-q", branch)
        for p in deletes:
            _git(repo, "rm", "-r", "-q", "--ignore-unmatch", "--", p.rstrip("/"))
        for p, data in writes:
            (repo / p).parent.mkdir(parents=True, exist_ok=True)
            (repo / p).write_bytes(data)
        _git(repo, "add", "-A")
        summary = header["value"].get("summary") or "commit"
        description = header["value"].get("description") or ""
        _git(repo, "commit", "-q", "--allow-empty", "-m", summary, "-m", description)
        oid = _git(repo, "rev-parse", "HEAD").strip()
        return {"commitUrl": f"{base}/{rid}/commit/{oid}", "commitOid": oid, "success": True}

    def tree(self, repo: Path, revision: str, path: str, recursive: bool) -> list[dict]:
        rev = self._rev(repo, revision)
        args = ["ls-tree", "-l", "-t"] + (["-r"] if recursive else []) + [rev]
        if path:
            args.append(path.rstrip("/") + "/")
        items = []
        for line in _git(repo, *args).splitlines():
            meta, p = line.split("\t", 1)
            _, kind, oid, size = meta.split()
            if kind == "tree":
                items.append({"type": "directory", "oid": oid, "size": 0, "path": p})
            else:
                items.append({"type": "file", "oid": oid, "size": int(size), "path": p})
        return items

    def info(self, repo: Path, rid: str, revision: str) -> dict:
        sha = self._rev(repo, revision)
        files = _git(repo, "ls-tree", "-r", "--name-only", sha).splitlines()
        return {
            "id": rid,
            "sha": sha,
            "private": False,
            "siblings": [{"rfilename": f} for f in files],
        }

    def resolve(self, repo: Path, revision: str, path: str) -> RawFile:
        sha = self._rev(repo, revision)
        try:
            oid = _git(repo, "rev-parse", f"{sha}:{path}").strip()
        except subprocess.CalledProcessError:
            raise HubProtocolError(404, f"Entry not found: {path}", "EntryNotFound") from None
        data = subprocess.run(
            ["git", "cat-file", "blob", oid], cwd=repo, check=True, capture_output=True
        ).stdout
        return RawFile(data, {"X-Repo-Commit": sha, "ETag": f'"{oid}"'})

    # ------------------------------------------------------------------ dispatch
    def handle(self, method: str, url: str, headers, body: bytes, base: str) -> tuple[int, object]:
        parts = urlsplit(url)
        path, query = parts.path, parse_qs(parts.query)
        if path == "/api/whoami-v2":
            return 200, {"type": "user", "name": "fake-hub-user", "auth": {"type": "access_token"}}
        if method == "PUT" and path.startswith("/_lfs/"):
            oid = path.split("/")[2]
            if query.get("sig", [""])[0] != self._sign(oid):
                raise HubProtocolError(403, "bad or missing upload signature")
            self.lfs_put(oid, body)
            return 200, {}
        if method == "POST" and path.startswith("/_lfs/") and path.endswith("/verify"):
            if not (self.lfs / path.split("/")[2]).exists():
                raise HubProtocolError(404, "LFS object missing")
            return 200, {}
        if method == "POST" and path == "/api/validate-yaml":
            errors = self.validate_yaml(json.loads(body))
            return (400 if errors else 200), {"errors": errors, "warnings": []}
        if method == "POST" and path == "/api/repos/create":
            return self.create_repo(json.loads(body), base)
        m = _LFS_BATCH.match(path)
        if m and method == "POST":
            self._repo(m[1] or "models", m[2], m[3])
            return 200, self.lfs_batch(json.loads(body), base)
        m = _RESOLVE.match(path)
        if m and method in ("GET", "HEAD"):
            return 200, self.resolve(self._repo(m[1] or "models", m[2], m[3]), m[4], unquote(m[5]))
        m = _API.match(path)
        if m is None:
            raise HubProtocolError(404, f"the fake hub has no route for {method} {path}")
        repo_type, org, name, rest = m[1], m[2], m[3], m[4] or ""
        repo, rid = self._repo(repo_type, org, name), f"{org}/{name}"
        action, _, arg = rest.partition("/")
        if method == "GET" and action in ("", "revision"):
            return 200, self.info(repo, rid, arg or "main")
        if method == "GET" and action == "refs":
            return 200, {
                "branches": self._refs(repo, "refs/heads"),
                "tags": self._refs(repo, "refs/tags"),
                "converts": [],
            }
        if method == "GET" and action == "tree":
            revision, _, sub = arg.partition("/")
            recursive = query.get("recursive", ["False"])[0].lower() in ("1", "true")
            return 200, self.tree(repo, revision, unquote(sub), recursive)
        if method == "POST" and action == "preupload":
            return 200, self.preupload(repo, arg, json.loads(body))
        if method == "POST" and action == "commit":
            if self.on_commit is not None:
                self.on_commit()
            if self.fail_commits > 0:
                self.fail_commits -= 1
                raise HubProtocolError(500, "Internal Error - We're working hard to fix this")
            lines = [json.loads(x) for x in body.splitlines() if x.strip()]
            prefix = "" if repo_type == "models" else "datasets/"
            return 200, self.commit(repo, arg, lines, base, prefix + rid)
        if method == "POST" and action == "branch":
            branch = unquote(arg)
            if branch in {r["name"] for r in self._refs(repo, "refs/heads")}:
                return 409, {"error": f"branch {branch} already exists"}
            start = (json.loads(body or b"{}") or {}).get("startingPoint") or "main"
            _git(repo, "branch", branch, self._rev(repo, start))
            return 200, {}
        if method == "POST" and action == "tag":
            spec = json.loads(body)
            if spec["tag"] in {r["name"] for r in self._refs(repo, "refs/tags")}:
                return 409, {"error": f"tag {spec['tag']} already exists"}
            _git(repo, "tag", spec["tag"], self._rev(repo, arg))
            return 200, {}
        if method == "DELETE" and action == "tag":
            tag = unquote(arg)
            if tag not in {r["name"] for r in self._refs(repo, "refs/tags")}:
                raise HubProtocolError(404, f"tag {tag} not found", "RevisionNotFound")
            _git(repo, "tag", "-d", tag)
            return 200, {}
        raise HubProtocolError(404, f"the fake hub has no route for {method} {path}")

    # ------------------------------------------------------------------ server
    def serve(self, host: str = "127.0.0.1", port: int = 0) -> str:
        """Start serving in a daemon thread; returns the endpoint URL."""
        hub = self

        class Handler(BaseHTTPRequestHandler):
            protocol_version = "HTTP/1.1"

            def log_message(self, *args):  # quiet
                pass

            def _body(self) -> bytes:
                if "chunked" in (self.headers.get("Transfer-Encoding") or "").lower():
                    chunks = []
                    while True:  # <hex size>\r\n<data>\r\n ... 0\r\n\r\n
                        size = int(self.rfile.readline().split(b";")[0].strip(), 16)
                        if size == 0:
                            while self.rfile.readline() not in (b"\r\n", b"\n", b""):
                                pass
                            return b"".join(chunks)
                        chunks.append(self.rfile.read(size))
                        self.rfile.readline()
                length = int(self.headers.get("Content-Length") or 0)
                return self.rfile.read(length) if length else b""

            def _do(self):
                body = self._body()
                base = f"http://{self.headers.get('Host')}"
                hub.requests.append((self.client_address[0], self.command, self.path))
                try:
                    auth = self.headers.get("Authorization", "")
                    presigned = self.command == "PUT" and self.path.startswith("/_lfs/")
                    if not presigned and (not auth.startswith("Bearer ") or len(auth) <= 7):
                        raise HubProtocolError(401, "Invalid credentials in Authorization header")
                    with hub.lock:
                        status, payload = hub.handle(
                            self.command, self.path, self.headers, body, base
                        )
                    code = None
                except HubProtocolError as exc:
                    status, payload, code = exc.status, {"error": exc.message}, exc.code
                raw = isinstance(payload, RawFile)
                data = payload.data if raw else json.dumps(payload).encode()
                self.send_response(status)
                for key, value in (payload.headers if raw else {}).items():
                    self.send_header(key, value)
                self.send_header(
                    "Content-Type", "application/octet-stream" if raw else "application/json"
                )
                self.send_header("Content-Length", str(len(data)))
                if code:
                    self.send_header("X-Error-Code", code)
                    self.send_header("X-Error-Message", payload["error"])
                self.end_headers()
                if self.command != "HEAD":
                    self.wfile.write(data)

            do_GET = do_POST = do_PUT = do_DELETE = do_HEAD = _do

        self.server = ThreadingHTTPServer((host, port), Handler)
        threading.Thread(target=self.server.serve_forever, daemon=True).start()
        return f"http://{host}:{self.server.server_address[1]}"

    def close(self) -> None:
        if self.server is not None:
            self.server.shutdown()
            self.server.server_close()

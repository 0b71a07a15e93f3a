"""Run a Python script as a Hub client with a guard: ``python _client.py SCRIPT [ARGS...]``.

The caller sets HF_ENDPOINT / HF_HOME / HF_HUB_DISABLE_XET in the environment, so they are in place
before anything imports huggingface_hub.  An audit hook records every socket connection the process
(any thread) opens; a connection to anything but the loopback address aborts the run with exit code
97, so "no request leaves 127.0.0.1" is checked, not assumed.
"""

import ipaddress
import os
import runpy
import sys
import traceback


def _loopback(host) -> bool:
    if isinstance(host, bytes):
        host = host.decode()
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return host == "localhost"


def _guard(event, args):
    if event == "socket.connect" and isinstance(args[1], tuple) and args[1]:
        target = args[1]
    elif event == "socket.getaddrinfo" and args[0] is not None:
        target = (args[0], args[1])
    else:
        return
    if not _loopback(target[0]):
        sys.stderr.write(f"NON-LOOPBACK CONNECTION to {target}\n")
        traceback.print_stack(file=sys.stderr)  # who tried: the test prints it
        sys.stderr.flush()
        os._exit(97)


sys.addaudithook(_guard)
script = sys.argv[1]
sys.argv = sys.argv[1:]
runpy.run_path(script, run_name="__main__")

"""Why pip failed, in one sentence a user can act on, from its whole output (the cause is rarely
its last line): no pip, a refused certificate, a full disk, no network, no wheel for this Python."""

from __future__ import annotations

import re

_NETWORK = ("NewConnectionError", "Name or service not known", "Temporary failure in name resolution",
            "Max retries exceeded", "ProxyError", "ConnectTimeoutError", "Network is unreachable",
            "ReadTimeoutError", "Connection refused")


def explain_failure(output: str, python_version: tuple[int, int], torch_index: str = "",
                    own_torch: bool = False) -> str:
    """One sentence naming why pip failed, from its whole output (the cause is rarely the last line).
    ``own_torch``: the interpreter's own torch is used (none is being installed)."""
    python = f"Python {python_version[0]}.{python_version[1]}"
    if re.search(r"No module named pip\b", output):
        return (f"This Blender's Python ({python}) has no pip. Install it with the system's package manager "
                "(Debian, Ubuntu: sudo apt install python3-pip), or use a Blender from blender.org, which "
                "bundles pip")
    if "CERTIFICATE_VERIFY_FAILED" in output or "SSLError" in output:
        return "The package index's certificate was refused (SSL): check the system's CA certificates or proxy"
    if "No space left on device" in output:
        need = ("0.5 GB beside this Python's own torch" if own_torch
                else "1.5 GB with the CPU build of torch" if torch_index
                else "8 GB with PyPI's torch, the CUDA build on Linux, and its download")
        return f"The disk is full: free space for the packages (about {need})"
    missing = re.search(r"No matching distribution found for ([^\s;]+)", output)
    if any(marker in output for marker in _NETWORK):
        host = re.search(r"host='([^']+)'", output) or re.search(r"https?://([^/\s]+)", output)
        where = host.group(1) if host else "the package index"
        if not missing or (torch_index and "torch" in missing.group(1)):
            return (f"Cannot reach {where}: check the network connection (and any proxy)"
                    + (f"; the torch index is {torch_index} (add-on preferences)" if torch_index else ""))
    if missing:
        return (f"No wheel of {missing.group(1)} for {python} on this platform"
                + (f" at the torch index {torch_index}" if torch_index and "torch" in missing.group(1) else "")
                + ": this Blender's Python is not supported by that version")
    if "THESE PACKAGES DO NOT MATCH THE HASHES" in output:
        return "A download was corrupted (hash mismatch): try again"
    if "metadata-generation-failed" in output:
        return ("pip could not prepare a downloaded source archive (metadata-generation-failed): "
                "its build needs setuptools from the package index")
    if "externally-managed-environment" in output:
        return f"This {python} refuses installs into itself (externally managed)"
    errors = [line.strip() for line in output.splitlines() if line.strip().startswith("ERROR:")]
    if errors:
        return errors[0].removeprefix("ERROR:").strip()
    lines = [line.strip() for line in output.splitlines() if line.strip()]
    return lines[-1] if lines else "pip failed without a message"

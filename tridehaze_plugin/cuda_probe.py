"""Whether CUDA can be used, asked once in a way that keeps a failed start to one line.

torch reports a CUDA start that fails (a GPU machine under an address-space limit, a broken
driver) as a multi-line UserWarning the first time anything asks; printed, it breaks the one-line
error every bad input gets (seen on an H200 under the memory-limit tests, docs/gpu.md). Every
probe of CUDA in the package goes through here, so whichever asks first keeps the warning in.
"""

from __future__ import annotations

import re
import warnings

import torch


def cuda_status() -> tuple[bool, str | None]:
    """Whether CUDA is usable, and why its start failed where it did (else None). Other
    warnings the probe raises still reach the user."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        available = torch.cuda.is_available()
    failure = None
    for w in caught:
        text = str(w.message)
        if "CUDA initialization" not in text:
            warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
            continue
        found = re.search(r"Error \d+: ([^(]+)", text)
        failure = (found.group(1) if found else text.splitlines()[0]).strip()
    return available, failure


def cuda_available() -> bool:
    """``torch.cuda.is_available()`` without torch's warning on a failed start."""
    return cuda_status()[0]

# Copyright 2026 valve_sim developers
#
# Licensed under the Apache License, Version 2.0 (the "License");
# you may not use this file except in compliance with the License.
# You may obtain a copy of the License at
#
#     http://www.apache.org/licenses/LICENSE-2.0
#
# Unless required by applicable law or agreed to in writing, software
# distributed under the License is distributed on an "AS IS" BASIS,
# WITHOUT WARRANTIES OR CONDITIONS OF ANY KIND, either express or implied.
# See the License for the specific language governing permissions and
# limitations under the License.

"""
Every file valve_sim writes, written one way: whole or not at all, and never through a link.

replacing() writes a file through a temporary file in its folder, renamed over it when
complete: a full disk, a crash or Ctrl-C leaves the file as it was (or absent), never
half written. The rename replaces whatever is at the path, so a symbolic link planted
at an output path the user did not name (a file inside --out DIR, a default name such
as BAG.repaired.mcap) is replaced, not followed. A path the user named itself
(explicit=True) is written where it leads, a link resolved first, as the user meant.
create_new() and append_to() open files that grow while they are written (a
recording, a results file) without following a link. json_text() is strict JSON: a
number that is not finite is written as null, never as NaN or Infinity. A file that
cannot be written is an OutputFileError naming the path the user knows (a user's
error, core.errors), raised here where the file is opened. make_folder()
creates an output folder, or says which one it could not create.
"""

from contextlib import contextmanager
import errno
import json
import math
import os
from pathlib import Path
import tempfile

from valve_sim.core.errors import output_error, OutputFileError

NO_LINK = os.O_NOFOLLOW | os.O_CLOEXEC
# What a write meets when the file system refuses more (full, over quota, read-only, too big).
STORAGE_ERRORS = (errno.ENOSPC, errno.EDQUOT, errno.EROFS, errno.EFBIG)


def _umask():
    mask = os.umask(0)
    os.umask(mask)
    return mask


FILE_MODE = 0o666 & ~_umask()  # what open() would give a new file


@contextmanager
def replacing(path, mode='w', explicit=False, **options):
    """
    Yield a stream to write path with; the file is replaced only if the block completes.

    mode and options as for open() ('w', 'wb', newline=...). explicit: the user named
    path (a link there is followed). An existing directory at path is an
    IsADirectoryError; a file that cannot be written an OutputFileError.
    """
    path = Path(os.path.realpath(path) if explicit else os.path.abspath(path))
    if path.is_dir() and not path.is_symlink():
        raise IsADirectoryError(21, 'is a directory, not a file', str(path))
    try:
        descriptor, temporary = tempfile.mkstemp(
            prefix=f'.{path.name}.', suffix='.part', dir=path.parent
        )
    except OSError as error:  # named as the file the user knows
        raise output_error(error, path) from None
    try:
        with os.fdopen(descriptor, mode, **options) as stream:
            yield stream
        os.chmod(temporary, FILE_MODE)
        os.replace(temporary, path)
    except BaseException as error:
        try:
            os.unlink(temporary)
        except OSError:
            pass
        if isinstance(error, OSError) and (
            error.filename == temporary or error.errno in STORAGE_ERRORS
        ):
            raise output_error(error, path) from None
        raise


def write_text(path, text, explicit=False):
    """Replace path with text (replacing())."""
    with replacing(path, 'w', explicit) as stream:
        stream.write(text)


def create_new(path):
    """Open a new file for writing in binary: FileExistsError if anything is at path."""
    return os.fdopen(os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL | NO_LINK, 0o666), 'wb')


def append_to(path):
    """Open path to append text; an OutputFileError (ELOOP) if it is a symbolic link."""
    try:
        return os.fdopen(os.open(path, os.O_WRONLY | os.O_APPEND | NO_LINK), 'a')
    except OSError as error:
        raise output_error(error, path) from None


def finite(value):
    """Return a JSON-ready copy of value with every float that is not finite as None."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {key: finite(item) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return [finite(item) for item in value]
    return value


def json_text(document, indent=2):
    """Return strict JSON of document: non-finite numbers as null (finite())."""
    return json.dumps(finite(document), indent=indent, allow_nan=False)


def make_folder(path):
    """Create the output folder path (and its parents); an OutputFileError naming it if not."""
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as error:
        raise OutputFileError(
            f'output folder {path} cannot be created: {error.strerror}'
        ) from error
    return path

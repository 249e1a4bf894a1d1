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
A path that exists must be a regular file: a device or a FIFO the user named is
written to directly (/dev/stdout, a pipe with a reader), never replaced; one inside an
output folder is refused (target()). create_new(), fresh_file() and append_to() open
files that grow while they are written (a recording, a node's log, a results file)
without following a link; named_file() a recording the user named (a regular file).
json_text() is strict JSON: a number that is not finite is written as null, never as
NaN or Infinity; xml_bytes() is well-formed XML whatever the text (characters XML
cannot hold written as escapes). safe_name() makes a name read from a file
(a scenario's) one path component. A file that cannot be written is an
OutputFileError naming the path the user knows (a user's error, core.errors), raised
here where the file is opened. make_folder() creates an output folder and its
subfolders (a link at a subfolder replaced, never followed out), or says which one it
could not create.
"""

from contextlib import contextmanager
import errno
import io
import json
import math
import os
from pathlib import Path
import re
import stat
import tempfile
import time
import xml.etree.ElementTree as ElementTree

from valve_sim.core.errors import output_error, OutputFileError, OutputFolderError

NO_LINK = os.O_NOFOLLOW | os.O_CLOEXEC
# What a write meets when the file system refuses more (full, over quota, read-only, too big),
# or a pipe whose reader has gone.
STORAGE_ERRORS = (errno.ENOSPC, errno.EDQUOT, errno.EROFS, errno.EFBIG, errno.EPIPE)
KINDS = ((stat.S_ISCHR, 'a character device'), (stat.S_ISBLK, 'a block device'),
         (stat.S_ISFIFO, 'a FIFO'), (stat.S_ISSOCK, 'a socket'))
# What XML 1.0 cannot hold (control characters, lone surrogates, U+FFFE/U+FFFF).
NOT_XML = re.compile('[^\t\n\r\x20-\ud7ff\ue000-\ufffd\U00010000-\U0010ffff]')
NOT_IN_NAME = re.compile(r'[^\w.+-]+')
NAME_LENGTH = 100  # [characters] of a name made from a file's text
FIFO_WAIT = 5.0  # [s] for a FIFO the user named to have a reader


def _umask():
    mask = os.umask(0)
    os.umask(mask)
    return mask


FILE_MODE = 0o666 & ~_umask()  # what open() would give a new file


def target(path, explicit=False):
    """
    Return (where to write path, in place): how replacing() writes it.

    Nothing or a regular file there: replaced whole (in place False), at the path a link
    leads to if explicit (the user named it), else at path (a link there replaced). A
    character device or a FIFO the user named: written to in place (True). A folder is an
    OutputFolderError (an IsADirectoryError); anything else (a device or FIFO inside an
    output folder, a socket) an OutputFileError in one line.
    """
    path = Path(path)
    try:
        status = os.stat(path) if explicit else os.lstat(path)
    except FileNotFoundError:
        status = None
    except OSError as error:  # a loop of links, a folder not searchable
        raise output_error(error, path) from None
    mode = status.st_mode if status else stat.S_IFREG
    if stat.S_ISREG(mode) or stat.S_ISLNK(mode):
        return Path(os.path.realpath(path) if explicit else os.path.abspath(path)), False
    if stat.S_ISDIR(mode):
        raise OutputFolderError(errno.EISDIR, 'is a directory, not a file', str(path))
    if explicit and (stat.S_ISCHR(mode) or stat.S_ISFIFO(mode)):
        return path, True
    raise OutputFileError(f'{path} is {_kind(mode)}, not a regular file: not written there')


def _kind(mode):
    return next(name for test, name in KINDS if test(mode))


@contextmanager
def replacing(path, mode='w', explicit=False, **options):
    """
    Yield a stream to write path with; the file is replaced only if the block completes.

    mode and options as for open() ('w', 'wb', newline=...). explicit: the user named
    path (a link there is followed; a device or FIFO there written in place, target()).
    An existing directory at path is an OutputFolderError; a file that cannot be
    written an OutputFileError.
    """
    written, in_place = target(path, explicit)
    if 'b' not in mode:  # text from anywhere (a path's undecodable bytes) written, escaped
        options.setdefault('errors', 'backslashreplace')
    if in_place:
        buffer = io.BytesIO()
        stream = buffer if 'b' in mode else io.TextIOWrapper(buffer, **options)
        yield stream
        stream.flush()
        _write_in_place(written, buffer.getvalue())
        return
    try:
        descriptor, temporary = tempfile.mkstemp(
            prefix=f'.{written.name}.', suffix='.part', dir=written.parent
        )
    except OSError as error:  # named as the file the user knows
        raise output_error(error, written) from None
    try:
        with os.fdopen(descriptor, mode, **options) as stream:
            yield stream
        os.chmod(temporary, FILE_MODE)
        os.replace(temporary, written)
    except BaseException as error:
        try:
            os.unlink(temporary)
        except OSError:
            pass
        if isinstance(error, OSError) and (
            error.filename == temporary or error.errno in STORAGE_ERRORS
        ):
            raise output_error(error, written) from None
        raise


def _open_in_place(path):
    """Open the device or FIFO at path to write; a FIFO with no reader by FIFO_WAIT is refused."""
    deadline = time.monotonic() + FIFO_WAIT
    while True:
        try:
            descriptor = os.open(path, os.O_WRONLY | os.O_NONBLOCK | os.O_CLOEXEC)
            os.set_blocking(descriptor, True)
            return descriptor
        except OSError as error:
            if error.errno != errno.ENXIO:
                raise output_error(error, path) from None
            if time.monotonic() > deadline:
                raise OutputFileError(f'{path} is a FIFO with no reader: not written') from None
            time.sleep(0.02)


def _write_in_place(path, data):
    """Write data to the device or FIFO at path (_open_in_place())."""
    descriptor = _open_in_place(path)
    try:
        view = memoryview(data)
        while view:
            view = view[os.write(descriptor, view):]
    except OSError as error:
        raise output_error(error, path) from None
    finally:
        os.close(descriptor)


def write_text(path, text, explicit=False):
    """Replace path with text (replacing())."""
    with replacing(path, 'w', explicit) as stream:
        stream.write(text)


def named_file(path):
    """
    Open a file the user named to record into, in binary; its writer seeks in it.

    A link is followed; a device, FIFO, folder or socket is refused in one line (a
    recording cannot seek in a pipe). An OutputFileError if it cannot be opened.
    """
    written, in_place = target(path, explicit=True)
    if in_place:
        raise OutputFileError(f'{path} is {_kind(os.stat(path).st_mode)}, not a regular file: '
                              'a recording needs a file it can seek in')
    try:
        return open(written, 'wb')
    except OSError as error:
        raise output_error(error, path) from None


def create_new(path):
    """Open a new file for writing in binary: FileExistsError if anything is at path."""
    return os.fdopen(os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL | NO_LINK, 0o666), 'wb')


def fresh_file(path, mode='wb'):
    """
    Open path inside an output folder to write from empty (a node's log), in mode.

    A link at path is replaced, not followed; a device, FIFO or folder there refused
    (target()); an OutputFileError if it cannot be opened.
    """
    target(path)
    try:
        if os.path.islink(path):
            os.unlink(path)
        descriptor = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC | NO_LINK, 0o666)
    except OSError as error:
        raise output_error(error, path) from None
    return os.fdopen(descriptor, mode)


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


def xml_text(text):
    r"""Return text with each character XML cannot hold written as its escape (\x01, \udc80)."""
    return NOT_XML.sub(lambda found: ascii(found[0])[1:-1], text)


def xml_bytes(root):
    """Return the XML document of an ElementTree root as UTF-8 bytes, well-formed, indented."""
    for element in root.iter():
        element.text = element.text and xml_text(element.text)
        element.tail = element.tail and xml_text(element.tail)
        element.attrib = {xml_text(key): xml_text(value) for key, value in element.attrib.items()}
    ElementTree.indent(root)
    return ElementTree.tostring(root, encoding='utf-8', xml_declaration=True) + b'\n'


def safe_name(text):
    """Return text from a file (a scenario's name) as one safe path component, not empty."""
    name = NOT_IN_NAME.sub('_', text).strip('.')[:NAME_LENGTH]
    return name or 'unnamed'


def make_folder(path, subfolders=()):
    """
    Create the output folder path (and its parents) and its subfolders; returns path.

    A link at a subfolder's name is replaced by a folder, never followed out of path.
    An OutputFileError names the folder that cannot be created.
    """
    path = Path(path)
    for folder in (path, *(path / name for name in subfolders)):
        try:
            if folder != path and folder.is_symlink():
                folder.unlink()
            folder.mkdir(parents=True, exist_ok=True)
        except OSError as error:
            raise OutputFileError(
                f'output folder {folder} cannot be created: {error.strerror}'
            ) from error
    return path

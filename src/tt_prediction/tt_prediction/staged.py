"""Folders of output written all at once: a failed or interrupted run leaves nothing behind.

Used by tt-identify (the report), tt-predict --tracks (the replay rows) and tt-perceive (the
tracks); single files (a rig's calibrated pose, the lead-time report) by
:func:`replace_file`; standard library only (tempfile and rename: no installable library
does this one step).
"""

import contextlib
import os
import shutil
import sys
import tempfile


def interruptible(tool, body, argv=None):
    """``body(argv)``, a command's work; Ctrl-C (KeyboardInterrupt) ends it with the line
    ``<tool>: interrupted`` on stderr and exit status 130, as a shell reports a SIGINT, and
    no traceback (a staged output is then not moved into place). A KeyboardInterrupt raised
    inside a compiled (numba) function reaches here as the SystemError it caused; so does it
    count."""
    try:
        return body(argv)
    except (KeyboardInterrupt, SystemError) as exc:
        if not _caused_by_interrupt(exc):
            raise
        print(f'{tool}: interrupted', file=sys.stderr)
        return 130


def _caused_by_interrupt(exc):
    """True when ``exc`` is a KeyboardInterrupt or was raised while handling one."""
    seen = set()
    while exc is not None and id(exc) not in seen:
        if isinstance(exc, KeyboardInterrupt):
            return True
        seen.add(id(exc))
        exc = exc.__cause__ or exc.__context__
    return False


def output_folder_error(out, ours, tool, csv_header=None):
    """Why ``out`` cannot take ``tool``'s output, or '': it must be missing, or a folder (not
    a link) whose files all match ``ours`` (a compiled regular expression of the names the
    tool writes), so that an output given as the input's folder, the data's parent or a file
    by mistake is refused before any work rather than overwritten or replaced. With
    ``csv_header`` (the tool's CSV header line), a CSV file must also begin with it: a name
    alone does not tell a measured track from the tool's output.

    The folder judged is the one :func:`staged_folder` writes, ``os.path.abspath(out)``: an
    empty ``out`` (an unset shell variable) is refused, and ``missing/..`` is the current
    folder, as it would be written."""
    if not out:
        return "--out '': an empty path (give the output folder)"
    path = os.path.abspath(out)
    if not os.path.lexists(path):
        return creatable_error(out)
    if os.path.islink(path) or not os.path.isdir(path):
        return f'--out {out}: not a folder'
    try:
        others = sorted(n for n in os.listdir(path)
                        if not (ours.fullmatch(n) or _holder(path, n))
                        or not _begins(path, n, csv_header))
    except OSError as exc:
        return f'--out {out}: cannot read: {exc.strerror}'
    if not others:
        return ''
    more = f' and {len(others) - 1} more' if len(others) > 1 else ''
    return (f'--out {out}: holds {others[0]}{more}, not written by {tool} (it would be '
            'overwritten or removed): give a new folder')


def _holder(folder, name):
    """Whether ``name`` in ``folder`` is a temporary folder :func:`staged_folder` made there
    (``.tt-<tool>-...``) and a killed run left: the next run removes it."""
    return name.startswith('.tt-') and os.path.isdir(os.path.join(folder, name))


def _begins(folder, name, csv_header):
    """Whether the file ``name`` of ``folder`` is not a CSV or begins with ``csv_header``
    (always, without one)."""
    if csv_header is None or not name.endswith('.csv'):
        return True
    with open(os.path.join(folder, name), 'rb') as f:
        return f.readline().rstrip(b'\r\n') == csv_header.encode()


def creatable_error(out, option='--out'):
    """Why the missing folder ``out`` (given as ``option``) could not be made, or '': a
    folder is made and removed in its nearest existing ancestor (where :func:`staged_folder`
    would work), so that a place that takes no folder (/proc, a read-only disk, a file as a
    parent) is refused before minutes of work rather than at their end."""
    ancestor = os.path.dirname(os.path.abspath(out))
    while not os.path.lexists(ancestor):
        ancestor = os.path.dirname(ancestor)
    try:
        os.rmdir(tempfile.mkdtemp(prefix='.tt-check-', dir=ancestor))
    except OSError as exc:
        return f'{option} {out}: cannot write: {exc.strerror or exc}'
    return ''


def replace_file(path, text):
    """Write ``text`` to the file ``path`` all at once: into a temporary file beside it, then
    renamed over it, so that an interrupted write leaves the old file. A link is followed (it
    stays a link) and an existing file's mode is kept."""
    target = os.path.realpath(path)
    tmp = f'{target}.tmp-{os.getpid()}'
    try:
        with open(tmp, 'w', encoding='utf-8') as f:
            f.write(text)
        if os.path.exists(target):
            shutil.copymode(target, tmp)
        os.replace(tmp, target)
    finally:
        if os.path.exists(tmp):
            os.remove(tmp)


@contextlib.contextmanager
def staged_folder(out_dir, prefix):
    """Yield a fresh temporary folder next to ``out_dir`` to write the outputs into.

    When the block ends without an exception the new folder takes the place of ``out_dir``
    (with the mode of any new folder: 0777 less the umask); nothing of an earlier output
    stays. On an exception the temporary folder is removed and ``out_dir`` is left as it
    was.

    An existing ``out_dir`` that cannot be swapped (a mount point, or a parent folder that
    takes no new folder) keeps its place and mode: the outputs are then written into a
    temporary folder inside it (on its file system), and once they are all written each
    takes the place of the file of its name (``os.replace``: whole, old or new), then the
    earlier output's other files are removed. An interruption during those renames (a few
    milliseconds) can leave a mix of the two outputs, never a half-written file; an error
    before them leaves ``out_dir`` as it was.
    """
    out_dir = os.path.abspath(out_dir)
    parent = os.path.dirname(out_dir)
    os.makedirs(parent, exist_ok=True)
    # A private holder (mkdtemp: a unique name, mode 0700) next to out_dir; the folder that
    # becomes out_dir is made in it by mkdir, so that it gets the umask's mode, not 0700.
    holder = None
    if not os.path.ismount(out_dir):             # False for a missing folder too
        try:
            holder = tempfile.mkdtemp(prefix=f'.{prefix}-', dir=parent)
        except OSError:
            if not os.path.isdir(out_dir):
                raise
    in_place = holder is None
    if in_place:
        holder = tempfile.mkdtemp(prefix=f'.{prefix}-', dir=out_dir)
    tmp = os.path.join(holder, 'new')
    try:
        os.mkdir(tmp)
        yield tmp
        if in_place:
            _replace_contents(out_dir, tmp, holder)
        elif not os.path.exists(out_dir):
            os.rename(tmp, out_dir)
        else:
            previous = os.path.join(holder, 'previous')
            try:
                os.rename(out_dir, previous)
            except OSError:             # busy (a bind mount ismount does not see), denied
                _replace_contents(out_dir, tmp, holder)
            else:
                try:
                    os.rename(tmp, out_dir)
                except BaseException:
                    os.rename(previous, out_dir)
                    raise
    finally:
        shutil.rmtree(holder, ignore_errors=True)


def _replace_contents(out_dir, new, holder):
    """Put each entry of ``new`` in the place of ``out_dir``'s of that name, then remove
    ``out_dir``'s others (``holder`` aside; an earlier run's holder too)."""
    names = set(os.listdir(new))
    for name in sorted(names):
        src, dst = os.path.join(new, name), os.path.join(out_dir, name)
        if os.path.isdir(dst) and not os.path.islink(dst):
            shutil.rmtree(dst)
        try:
            os.replace(src, dst)
        except OSError:                 # another file system (a bind mount): copied
            shutil.move(src, dst)
    for name in os.listdir(out_dir):
        path = os.path.join(out_dir, name)
        if name in names or path == holder:
            continue
        if os.path.isdir(path) and not os.path.islink(path):
            shutil.rmtree(path)
        else:
            os.remove(path)

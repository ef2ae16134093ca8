"""Folders of output written all at once: a failed or interrupted run leaves nothing behind.

Used by tt-identify (the report) and tt-predict --tracks (the replay rows); standard library
only (tempfile and rename: no installable library does this one step).
"""

import contextlib
import os
import shutil
import tempfile


@contextlib.contextmanager
def staged_folder(out_dir, prefix, replace_folder):
    """Yield a fresh temporary folder next to ``out_dir`` to write the outputs into.

    When the block ends without an exception the outputs move into ``out_dir`` (created if
    missing): with ``replace_folder`` the whole folder is swapped for the new one (nothing of
    an earlier report stays), otherwise each new file replaces the one of the same name and
    other files in ``out_dir`` are kept. On an exception the temporary folder is removed and
    ``out_dir`` is left as it was.
    """
    out_dir = os.path.abspath(out_dir)
    parent = os.path.dirname(out_dir)
    os.makedirs(parent, exist_ok=True)
    tmp = tempfile.mkdtemp(prefix=f'.{prefix}-', dir=parent)
    try:
        yield tmp
        if not os.path.exists(out_dir):
            os.rename(tmp, out_dir)
        elif replace_folder:
            old = tempfile.mkdtemp(prefix=f'.{prefix}-old-', dir=parent)
            os.rename(out_dir, os.path.join(old, 'previous'))
            os.rename(tmp, out_dir)
            shutil.rmtree(old)
        else:
            for name in os.listdir(tmp):
                os.replace(os.path.join(tmp, name), os.path.join(out_dir, name))
            os.rmdir(tmp)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise

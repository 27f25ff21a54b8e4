"""Console entry point of ``thermal-imu-calib``: one BLAS thread, then ``cli.main``.

The CLI's fits are small dense problems: OpenBLAS threads only contend, and idle ones spin
(docs/speed.md, "BLAS threads"). ``cli.main`` limits them with threadpoolctl once it runs,
but numpy and scipy load (and start their threads) while ``cli`` is imported: about 0.2
CPU-s of spinning per run on this 2-core machine. Setting ``OPENBLAS_NUM_THREADS`` before
that import avoids it; a value the user set is kept, and child processes (fleet workers)
inherit it.
"""

import os
import sys


def main(argv=None):
    """Run ``thermal-imu-calib`` (``argv`` as for ``cli.main``)."""
    os.environ.setdefault('OPENBLAS_NUM_THREADS', '1')
    from .commands import main as cli_main
    return cli_main(argv)


if __name__ == '__main__':
    sys.exit(main())

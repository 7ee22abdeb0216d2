"""Convert the Aye & Ang 2018 piezo hysteresis data to the recording contract.

    .venv/bin/python scripts/convert_aye2018.py SOURCE_DIR [--force]

SOURCE_DIR holds Model_Vi_Do.dat and Test_Vi_Do_Di.dat (whitespace-separated, 200 Hz,
no header; column 1 the input voltage, column 5 the raw capacitive sensor). Writes
fixtures/aye2018/{model_vi_do,test_vi_do_di}.csv with time_s, voltage_V and sensor_V,
and copies the LICENSE that must travel with the data.
"""

import argparse
import shutil
from pathlib import Path

import numpy as np

import stickslip_jax as ss

OUT = Path(__file__).resolve().parent.parent / "fixtures" / "aye2018"
RATE_HZ = 200.0
FILES = {
    "Model_Vi_Do.dat": ("model_vi_do", "identification set, 1 Hz periodic input; the "
                        "authors fit one 200-sample cycle from row 3152 (1-based)"),
    "Test_Vi_Do_Di.dat": ("test_vi_do_di", "validation set; cycles without inverse "
                          "compensation from rows 3852 and 5052, with it from 11152 "
                          "and 11852 (1-based)"),
}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("source", type=Path)
    ap.add_argument("--force", action="store_true")
    args = ap.parse_args()
    OUT.mkdir(parents=True, exist_ok=True)
    for src, (name, what) in FILES.items():
        data = np.loadtxt(args.source / src)
        rec = ss.Recording(
            time_s=np.arange(len(data)) / RATE_HZ, voltage_V=data[:, 0], sensor_V=data[:, 4],
            meta={"source": f"Aye & Ang 2018, {src} (columns 1 and 5)",
                  "licence": "MIT (LICENSE in this folder)",
                  "content": what},
            name=name)
        ss.save_recording(rec, OUT / f"{name}.csv", force=args.force)
        print(f"{OUT / (name + '.csv')}: {len(data)} rows")
    shutil.copyfile(args.source / "LICENSE", OUT / "LICENSE")


if __name__ == "__main__":
    main()

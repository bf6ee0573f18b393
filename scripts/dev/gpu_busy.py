"""The GPUs' utilisation over a span of time, from a log of `nvidia-smi --query-gpu=timestamp,
index,utilization.gpu,... --format=csv,noheader,nounits -l 1`: per GPU the mean of its 1 s
samples between START and END (Unix seconds) and the share of samples at 0%.

    python scripts/dev/gpu_busy.py UTIL.csv START END
"""

from __future__ import annotations

import sys
from collections import defaultdict
from datetime import datetime, timezone


def main() -> None:
    path, start, end = sys.argv[1], float(sys.argv[2]), float(sys.argv[3])
    samples: dict[str, list[float]] = defaultdict(list)
    with open(path) as lines:
        for line in lines:
            fields = [field.strip() for field in line.split(",")]
            if len(fields) < 3:
                continue
            try:  # UTC: device_training.sh runs nvidia-smi with TZ=UTC
                moment = datetime.strptime(fields[0], "%Y/%m/%d %H:%M:%S.%f")
                busy = float(fields[2])
            except ValueError:
                continue
            if start <= moment.replace(tzinfo=timezone.utc).timestamp() <= end:
                samples[fields[1]].append(busy)
    if not samples:
        print("no samples in that span")
        return
    print(
        "; ".join(
            f"GPU {gpu}: {sum(values) / len(values):.0f}% mean of {len(values)} samples, "
            f"{sum(v == 0 for v in values) / len(values):.0%} at 0%"
            for gpu, values in sorted(samples.items())
        )
    )


if __name__ == "__main__":
    main()

# The JARA_ARM services in a container.
#   docker compose up --build            router + one container per service (compose.yaml)
#   docker run --rm -p 127.0.0.1:7447:7447 --cap-add SYS_NICE jara-arm
#                                        everything in one container (jara-arm up)

# Build stage: wheels for the package and every dependency. The compilers are
# here for dependencies without a binary wheel on the platform (pybullet on arm64).
FROM python:3.11-slim AS build
RUN apt-get update \
 && apt-get install -y --no-install-recommends build-essential \
 && rm -rf /var/lib/apt/lists/*
WORKDIR /src
COPY . .
RUN pip wheel --no-cache-dir --wheel-dir /wheels .

# Runtime: the package installed from those wheels, no compilers.
FROM python:3.11-slim
ENV PYTHONUNBUFFERED=1 \
    PIP_DISABLE_PIP_VERSION_CHECK=1
RUN --mount=type=bind,from=build,source=/wheels,target=/wheels \
    pip install --no-cache-dir --no-index --find-links /wheels jara-arm
# Root stays the user: CAP_SYS_NICE (cap_add) only reaches root's processes, and
# the servo loop needs it for SCHED_FIFO.
EXPOSE 7447
CMD ["jara-arm", "up", "--listen", "tcp/0.0.0.0:7447"]

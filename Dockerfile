# thermocomp: the daemon on the simulated bench by default. It listens on every interface of
# the container, so it needs a control token (without one it refuses to start, exit 2):
#   docker build -t thermocomp .
#   docker run -p 127.0.0.1:8000:8000 -e THERMOCOMP_API__CONTROL_TOKEN=change-me \
#     -v thermocomp-data:/data thermocomp
# (reads need the token too, or add -e THERMOCOMP_API__ANONYMOUS_READ=true). The dashboard
# and API accept the names localhost and 127.0.0.1; to reach them by another name add
# -e 'THERMOCOMP_API__ALLOWED_HOSTS=["lab-pc.example.org"]'.
# Real hardware: pass the devices and a lab config, e.g.
#   docker run --device /dev/ttyS0 --device /dev/video0 --device /dev/video1 \
#     -e THERMOCOMP_API__CONTROL_TOKEN=change-me -v /etc/thermocomp:/config:ro \
#     -v thermocomp-data:/data thermocomp serve --config /config/lab.toml
FROM python:3.11-slim AS build
WORKDIR /src
RUN python -m venv /opt/venv
ENV PATH=/opt/venv/bin:$PATH
# Dependencies in their own layer, exactly the hashed set of the lock (as make run installs):
# rebuilt only when the lock changes.
COPY requirements.lock ./
RUN pip install --no-cache-dir --require-hashes -r requirements.lock
COPY pyproject.toml README.md ./
COPY daemon daemon
COPY drivers drivers
COPY api api
COPY config config
RUN pip install --no-cache-dir --no-deps --no-build-isolation .

FROM python:3.11-slim
RUN useradd --system --uid 10001 --home-dir /data --create-home thermocomp
COPY --from=build /opt/venv /opt/venv
# The example configurations (the networks, arms and duty cycles are package data, inside the
# venv); arm-sim.toml is the simulated arm bench: serve --config /etc/thermocomp/arm-sim.toml
COPY config/sim.toml config/lab.toml config/arm-sim.toml /etc/thermocomp/
ENV PATH=/opt/venv/bin:$PATH \
    THERMOCOMP_STORAGE__DATA_DIR=/data \
    THERMOCOMP_API__HOST=0.0.0.0
USER thermocomp
WORKDIR /data
VOLUME ["/data"]
EXPOSE 8000
HEALTHCHECK --interval=30s --timeout=5s --start-period=20s \
    CMD python -c "import urllib.request,sys; sys.exit(0 if urllib.request.urlopen('http://127.0.0.1:8000/api/v1/health', timeout=4).status == 200 else 1)"
ENTRYPOINT ["thermocomp"]
CMD ["serve", "--config", "/etc/thermocomp/sim.toml"]

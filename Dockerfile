# thermocomp: the daemon on the simulated bench by default.
#   docker build -t thermocomp .
#   docker run -p 8000:8000 -v thermocomp-data:/data thermocomp
# Real hardware: pass the devices and a lab config, e.g.
#   docker run --device /dev/ttyS0 --device /dev/video0 --device /dev/video1 \
#     -v /etc/thermocomp:/config:ro -v thermocomp-data:/data thermocomp \
#     serve --config /config/lab.toml --host 0.0.0.0
FROM python:3.11-slim AS build
WORKDIR /src
RUN python -m venv /opt/venv
ENV PATH=/opt/venv/bin:$PATH
# Dependencies in their own layer: rebuilt only when pyproject.toml changes.
COPY pyproject.toml README.md ./
RUN mkdir -p daemon drivers api config && touch daemon/__init__.py drivers/__init__.py \
        api/__init__.py config/__init__.py \
    && pip install --no-cache-dir . && pip uninstall -y thermocomp
COPY daemon daemon
COPY drivers drivers
COPY api api
COPY config config
RUN pip install --no-cache-dir --no-deps .

FROM python:3.11-slim
RUN useradd --system --uid 10001 --home-dir /data --create-home thermocomp
COPY --from=build /opt/venv /opt/venv
# The example configurations (the networks are package data, inside the venv).
COPY config/sim.toml config/lab.toml /etc/thermocomp/
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

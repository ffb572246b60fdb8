# One image for the web server and the learner.
FROM python:3.11-slim-bookworm
ENV PYTHONDONTWRITEBYTECODE=1 PYTHONUNBUFFERED=1 MUJOCO_GL=egl PYOPENGL_PLATFORM=egl RAQ_DATA_DIR=/data
RUN apt-get update && apt-get install -y --no-install-recommends libegl1 libegl-mesa0 libgl1 libgles2 libosmesa6 \
    && rm -rf /var/lib/apt/lists/*
WORKDIR /srv/vice-raq
COPY pyproject.toml README.md alembic.ini ./
COPY app app
COPY cli cli
COPY contract contract
COPY learner learner
COPY robot robot
COPY sim sim
COPY migrations migrations
COPY templates templates
COPY static static
RUN pip install --no-cache-dir --extra-index-url https://download.pytorch.org/whl/cpu '.[postgres,objectstore]'
VOLUME /data
EXPOSE 8000
CMD ["raq", "serve", "--host", "0.0.0.0"]

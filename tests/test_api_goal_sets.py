"""Goal sets and uploads: good photos stored with model and display copies; bad input rejected, nothing stored."""

import io
from collections.abc import Callable

import pytest
from fastapi.testclient import TestClient
from PIL import Image

from contract.images import ImageRejected, decode_upload, to_png
from contract.store import Store


def _create(client: TestClient, name: str = "goals", **extra: object) -> dict:
    response = client.post("/api/goal-sets", json={"name": name, **extra})
    assert response.status_code == 201, response.text
    return response.json()


def test_create_list_and_duplicate(client: TestClient) -> None:
    goal_set = _create(client, "pusher goals")
    assert goal_set["image_size"] == 48 and goal_set["example_count"] == 0
    assert client.post("/api/goal-sets", json={"name": "pusher goals"}).status_code == 409
    assert client.post("/api/goal-sets", json={"name": ""}).status_code == 422
    assert [g["name"] for g in client.get("/api/goal-sets").json()] == ["pusher goals"]
    assert client.get("/api/goal-sets/999").status_code == 404


def test_upload_several_photos_makes_model_and_display_copies(
    client: TestClient, make_image: Callable[..., bytes]
) -> None:
    goal_set = _create(client)
    files = [
        ("files", ("wide.png", make_image((640, 320)), "image/png")),
        ("files", ("photo.jpg", make_image((300, 500), fmt="JPEG"), "image/jpeg")),
        ("files", ("small.webp", make_image((60, 60), fmt="WEBP"), "image/webp")),
    ]
    response = client.post(f"/api/goal-sets/{goal_set['id']}/examples", files=files)
    assert response.status_code == 201, response.text
    examples = response.json()
    assert [e["filename"] for e in examples] == ["wide.png", "photo.jpg", "small.webp"]
    assert [e["original_media_type"] for e in examples] == ["image/png", "image/jpeg", "image/webp"]
    assert (examples[0]["width"], examples[0]["height"]) == (640, 320)

    model = client.get(examples[0]["model_url"])
    assert model.status_code == 200 and model.headers["content-type"] == "image/png"
    assert Image.open(io.BytesIO(model.content)).size == (48, 48)
    display = Image.open(io.BytesIO(client.get(examples[0]["display_url"]).content))
    assert display.size == (256, 128)  # the whole photo, longest side 256
    original = client.get(examples[1]["original_url"])
    assert original.headers["content-type"] == "image/jpeg"
    assert Image.open(io.BytesIO(original.content)).size == (300, 500)

    detail = client.get(f"/api/goal-sets/{goal_set['id']}").json()
    assert detail["example_count"] == 3 and len(detail["examples"]) == 3
    assert len(client.get(f"/api/goal-sets/{goal_set['id']}/examples").json()) == 3


def test_model_size_follows_the_goal_set(client: TestClient, make_image: Callable[..., bytes]) -> None:
    goal_set = _create(client, image_size=64)
    example = client.post(
        f"/api/goal-sets/{goal_set['id']}/examples", files=[("files", ("a.png", make_image(), "image/png"))]
    ).json()[0]
    assert Image.open(io.BytesIO(client.get(example["model_url"]).content)).size == (64, 64)


def test_to_png_centre_crops_before_resizing(make_image: Callable[..., bytes]) -> None:
    image = Image.new("RGB", (300, 100), (0, 0, 255))
    image.paste((255, 0, 0), (100, 0, 200, 100))  # the centre square is red
    model = Image.open(io.BytesIO(to_png(image, 48)))
    assert model.size == (48, 48)
    assert model.getpixel((1, 1)) == (255, 0, 0) and model.getpixel((46, 46)) == (255, 0, 0)


@pytest.mark.parametrize(
    ("name", "payload", "status", "words"),
    [
        ("empty.png", b"", 400, "empty"),
        ("notes.txt", b"this is not an image at all", 400, "not an image"),
        ("animation.gif", "gif", 400, "not accepted"),
        ("truncated.png", "truncated", 400, "damaged or truncated"),
    ],
)
def test_bad_uploads_are_rejected(
    client: TestClient,
    store: Store,
    make_image: Callable[..., bytes],
    name: str,
    payload: object,
    status: int,
    words: str,
) -> None:
    if payload == "gif":
        payload = make_image(fmt="GIF")
    elif payload == "truncated":
        payload = make_image((400, 400), fmt="PNG")[:300]
    goal_set = _create(client)
    response = client.post(
        f"/api/goal-sets/{goal_set['id']}/examples", files=[("files", (name, payload, "application/octet-stream"))]
    )
    assert response.status_code == status, response.text
    assert words in response.json()["detail"] and name in response.json()["detail"]
    assert store.list_goal_examples(goal_set_id=goal_set["id"]) == []


def test_too_many_bytes_is_413(make_client: Callable[..., TestClient], make_image: Callable[..., bytes]) -> None:
    client = make_client(max_upload_bytes=2_000)
    goal_set = _create(client)
    big = make_image((300, 300), fmt="JPEG")
    assert len(big) > 2_000
    response = client.post(
        f"/api/goal-sets/{goal_set['id']}/examples", files=[("files", ("big.jpg", big, "image/jpeg"))]
    )
    assert response.status_code == 413
    assert "limit" in response.json()["detail"]


def test_decompression_bomb_is_413(make_client: Callable[..., TestClient], make_image: Callable[..., bytes]) -> None:
    client = make_client(max_image_pixels=100_000)
    goal_set = _create(client)
    bomb = make_image((2_000, 2_000))  # 4 Mpx of one colour: a few kB on the wire
    assert len(bomb) < 50_000
    response = client.post(
        f"/api/goal-sets/{goal_set['id']}/examples", files=[("files", ("bomb.png", bomb, "image/png"))]
    )
    assert response.status_code == 413
    assert "pixels" in response.json()["detail"]


def test_decode_upload_refuses_bombs_and_junk(make_image: Callable[..., bytes]) -> None:
    with pytest.raises(ImageRejected) as error:
        decode_upload(make_image((1_000, 1_000)), max_bytes=10**7, max_pixels=10_000)
    assert error.value.status_code == 413
    with pytest.raises(ImageRejected):
        decode_upload(b"\x89PNG\r\n\x1a\n" + b"\x00" * 40, max_bytes=10**7, max_pixels=10**7)
    image = decode_upload(make_image((20, 10)), max_bytes=10**7, max_pixels=10**7)
    assert image.size == (20, 10) and image.mode == "RGB"


def test_one_bad_file_rejects_the_whole_upload(
    client: TestClient, store: Store, make_image: Callable[..., bytes]
) -> None:
    goal_set = _create(client)
    files = [
        ("files", ("good1.png", make_image(), "image/png")),
        ("files", ("bad.png", b"garbage", "image/png")),
        ("files", ("good2.png", make_image(), "image/png")),
    ]
    response = client.post(f"/api/goal-sets/{goal_set['id']}/examples", files=files)
    assert response.status_code == 400
    assert "bad.png" in response.json()["detail"] and "nothing" in response.json()["detail"]
    assert store.list_goal_examples(goal_set_id=goal_set["id"]) == []


def test_upload_to_missing_set_or_without_files(client: TestClient, make_image: Callable[..., bytes]) -> None:
    response = client.post("/api/goal-sets/77/examples", files=[("files", ("a.png", make_image(), "image/png"))])
    assert response.status_code == 404
    goal_set = _create(client)
    assert client.post(f"/api/goal-sets/{goal_set['id']}/examples").status_code == 422


def test_image_routes_and_deletes(client: TestClient, make_image: Callable[..., bytes]) -> None:
    goal_set = _create(client)
    example = client.post(
        f"/api/goal-sets/{goal_set['id']}/examples", files=[("files", ("a.png", make_image(), "image/png"))]
    ).json()[0]
    url = f"/api/goal-examples/{example['id']}/image"
    assert client.get(url, params={"kind": "../../etc/passwd"}).status_code == 422
    assert client.get("/api/goal-examples/999/image").status_code == 404
    assert client.delete(f"/api/goal-examples/{example['id']}").status_code == 204
    assert client.get(url).status_code == 404
    assert client.delete(f"/api/goal-examples/{example['id']}").status_code == 404
    assert client.delete(f"/api/goal-sets/{goal_set['id']}").status_code == 204
    assert client.get(f"/api/goal-sets/{goal_set['id']}").status_code == 404
    assert client.delete(f"/api/goal-sets/{goal_set['id']}").status_code == 404


def _mpo_bytes(first: tuple[int, int, int], second: tuple[int, int, int], size: tuple[int, int] = (64, 48)) -> bytes:
    """A JPEG with an MPF segment and two frames, as phones save portrait and HDR photos."""
    buffer = io.BytesIO()
    Image.new("RGB", size, first).save(buffer, "MPO", save_all=True, append_images=[Image.new("RGB", size, second)])
    return buffer.getvalue()


def test_phone_mpo_jpegs_are_accepted_as_jpeg(client: TestClient) -> None:
    data = _mpo_bytes((220, 30, 30), (30, 30, 220))
    with Image.open(io.BytesIO(data)) as opened:
        assert opened.format == "MPO" and opened.n_frames == 2  # what Pillow makes of such a phone photo
    assert decode_upload(data, max_bytes=10**7, max_pixels=10**7).size == (64, 48)
    goal_set = _create(client)
    response = client.post(
        f"/api/goal-sets/{goal_set['id']}/examples", files=[("files", ("portrait.jpg", data, "image/jpeg"))]
    )
    assert response.status_code == 201, response.text
    example = response.json()[0]
    assert example["original_media_type"] == "image/jpeg"
    assert (example["width"], example["height"]) == (64, 48)
    model = Image.open(io.BytesIO(client.get(example["model_url"]).content)).convert("RGB")
    red, _green, blue = model.getpixel((24, 24))
    assert red > 150 and blue < 100  # the first frame (the photo), not the second
    original = client.get(example["original_url"])
    assert original.headers["content-type"] == "image/jpeg" and original.content == data


def test_request_over_the_upload_limit_is_413_before_parsing(
    make_client: Callable[..., TestClient], store: Store
) -> None:
    from app.routers.goal_sets import upload_request_limit

    client = make_client(max_upload_bytes=2_000)
    goal_set = _create(client)
    limit = upload_request_limit(2_000)
    # Not even valid multipart: were it parsed, the answer would be 400; the size alone decides first.
    headers = {"Content-Type": "multipart/form-data; boundary=xyz"}
    response = client.post(f"/api/goal-sets/{goal_set['id']}/examples", content=b"x" * (limit + 1), headers=headers)
    assert response.status_code == 413, response.text
    assert "limit for one request" in response.json()["detail"]
    # A chunked body (no Content-Length) is counted as it arrives.
    boundary = "testboundary"
    head = (
        f'--{boundary}\r\nContent-Disposition: form-data; name="files"; filename="huge.png"\r\n'
        "Content-Type: image/png\r\n\r\n"
    ).encode()

    def chunks():  # type: ignore[no-untyped-def]
        yield head
        for _ in range(limit // 65_536 + 2):
            yield b"\0" * 65_536
        yield f"\r\n--{boundary}--\r\n".encode()

    response = client.post(
        f"/api/goal-sets/{goal_set['id']}/examples",
        content=chunks(),
        headers={"Content-Type": f"multipart/form-data; boundary={boundary}"},
    )
    assert response.status_code == 413, response.text
    assert "limit for one request" in response.json()["detail"]
    assert store.list_goal_examples(goal_set_id=goal_set["id"]) == []


def test_too_many_files_in_one_upload_is_refused(
    client: TestClient, store: Store, make_image: Callable[..., bytes]
) -> None:
    from app.routers.goal_sets import MAX_FILES_PER_UPLOAD

    goal_set = _create(client)
    tiny = make_image((8, 8))
    files = [("files", (f"g{i}.png", tiny, "image/png")) for i in range(MAX_FILES_PER_UPLOAD + 1)]
    response = client.post(f"/api/goal-sets/{goal_set['id']}/examples", files=files)
    assert response.status_code in (400, 413), response.text
    assert str(MAX_FILES_PER_UPLOAD) in response.json()["detail"]
    assert store.list_goal_examples(goal_set_id=goal_set["id"]) == []

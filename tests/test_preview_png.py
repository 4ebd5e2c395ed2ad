"""The preview PNG's 8-bit codes: the sRGB curve's rounding, found by a search among the
values where the code changes (exr.srgb_codes)."""
import numpy as np

from mpp_render import exr


def test_the_codes_are_the_curves_rounding():
    rng = np.random.default_rng(5)
    x = np.concatenate([rng.random(200000) ** 3 * 1.3 - 0.05,         # below 0, above 1
                        np.linspace(0.0, 0.004, 5001),                 # the linear toe
                        [np.nan, np.inf, -np.inf, 0.0, 1.0]])
    want = np.round(exr.srgb_oetf(np.nan_to_num(x, nan=0.0)) * 255.0).astype(np.uint8)
    got = exr.srgb_codes(x)
    assert got.dtype == np.uint8
    np.testing.assert_array_equal(got, want)
    # the curve and its inverse agree, so each code's edge lies half a code from its value
    codes = np.arange(256) / 255.0
    np.testing.assert_allclose(exr.srgb_oetf(exr.srgb_eotf(codes)), codes, atol=1e-12)


def test_the_preview_png_holds_those_codes(tmp_path):
    img = np.zeros((4, 5, 4), np.float32)
    img[..., 0] = np.linspace(0.0, 1.2, 20).reshape(4, 5)
    img[1, 2, 1] = np.nan
    path = str(tmp_path / "p.png")
    exr.write_preview_png(path, img)
    from mpp_render.exr import _oiio
    inp = _oiio().ImageInput.open(path)
    px = inp.read_image(format="uint8")
    inp.close()
    np.testing.assert_array_equal(px[..., 0], exr.srgb_codes(img[..., 0]))
    assert px[1, 2, 1] == 0

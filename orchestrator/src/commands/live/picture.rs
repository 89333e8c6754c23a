//! Pictures as the page shows them: base64 text of a PNG (the robot's views, the maps) or a
//! JPEG (the person's films), inside the socket's JSON messages.

use base64::Engine;

/// A picture as PNG, base64.
pub fn png_base64<P: image::PixelWithColorType>(img: &image::ImageBuffer<P, Vec<P::Subpixel>>) -> anyhow::Result<String>
where
    [P::Subpixel]: image::EncodableLayout,
{
    let mut png = Vec::new();
    img.write_to(&mut std::io::Cursor::new(&mut png), image::ImageFormat::Png)?;
    Ok(base64::engine::general_purpose::STANDARD.encode(png))
}

/// An RGB picture as JPEG at `quality` (1–100), base64.
pub fn jpeg_base64(img: &image::RgbImage, quality: u8) -> anyhow::Result<String> {
    let mut jpeg = Vec::new();
    let (w, h) = (img.width().try_into()?, img.height().try_into()?);
    jpeg_encoder::Encoder::new(&mut jpeg, quality).encode(img.as_raw(), w, h, jpeg_encoder::ColorType::Rgb)?;
    Ok(base64::engine::general_purpose::STANDARD.encode(jpeg))
}

//! The robot's camera as the policy sees it: a real camera's colour and aligned depth images,
//! checked against its `camera_info`, cut to the field of view the policy was trained with and
//! sampled to its frame size. The policy learned from frames rasterized at 64 × 64 (one sample
//! at each pixel's centre), so each of its pixels takes the camera's pixel nearest that centre.

use super::msgs::{CameraInfo, Image};
use worker::camera::encode_depth;

/// The square view of the policy: its size and (vertical = horizontal) field of view.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PolicyView {
    pub size: u32,
    pub fov_deg: f32,
}

/// Where each of the policy's pixels is read in the camera's image: a column per x, a row per y.
#[derive(Clone, Debug, PartialEq)]
pub struct Sampling {
    pub width: u32,
    pub height: u32,
    cols: Vec<u32>,
    rows: Vec<u32>,
}

/// The camera's field of view (horizontal, vertical; degrees) from its intrinsics.
pub fn field_of_view(info: &CameraInfo) -> (f64, f64) {
    let (fx, fy) = (info.k[0], info.k[4]);
    let span = |f: f64, c: f64, n: u32| ((c + 0.5) / f).atan() + ((n as f64 - c - 0.5) / f).atan();
    (span(fx, info.k[2], info.width).to_degrees(), span(fy, info.k[5], info.height).to_degrees())
}

impl Sampling {
    /// The pixels `view` reads in a camera described by `info`, or why the camera cannot serve
    /// it (one line: a narrower view than the policy's cannot be widened).
    pub fn new(info: &CameraInfo, view: PolicyView) -> Result<Sampling, String> {
        let (fx, fy, cx, cy) = (info.k[0], info.k[4], info.k[2], info.k[5]);
        if !(fx > 0.0 && fy > 0.0) || info.width == 0 || info.height == 0 {
            return Err(format!(
                "camera_info: {}×{} with fx {fx} and fy {fy} describes no camera",
                info.width, info.height
            ));
        }
        let tan = (view.fov_deg as f64 / 2.0).to_radians().tan();
        let place = |i: u32, f: f64, c: f64, n: u32| -> Option<u32> {
            let u = (2.0 * (i as f64 + 0.5) / view.size as f64 - 1.0) * tan;
            let p = (c + f * u).round();
            (p >= 0.0 && p < n as f64).then_some(p as u32)
        };
        let cols: Option<Vec<u32>> = (0..view.size).map(|i| place(i, fx, cx, info.width)).collect();
        let rows: Option<Vec<u32>> = (0..view.size).map(|i| place(i, fy, cy, info.height)).collect();
        match (cols, rows) {
            (Some(cols), Some(rows)) => Ok(Sampling { width: info.width, height: info.height, cols, rows }),
            _ => {
                let (h, v) = field_of_view(info);
                Err(format!(
                    "the camera sees {h:.1}° × {v:.1}° ({}×{}); the policy was trained on {f}° × {f}°: \
                     it needs a camera at least that wide (or a policy trained with env.fov_deg to match)",
                    info.width,
                    info.height,
                    f = view.fov_deg
                ))
            }
        }
    }

    fn size(&self) -> usize {
        self.cols.len()
    }

    /// The camera's pixels of a row-major `width × height` image that the policy reads, row by
    /// row.
    pub fn pick<'a, T: Copy>(&'a self, image: &'a [T]) -> impl Iterator<Item = T> + 'a {
        let w = self.width as usize;
        self.rows.iter().flat_map(move |&r| self.cols.iter().map(move |&c| image[r as usize * w + c as usize]))
    }

    /// The colour image as the policy's RGB frame (`size² × 3`).
    pub fn colour(&self, img: &Image, out: &mut [u8]) -> Result<(), String> {
        let (channels, swap) = match img.encoding.as_str() {
            "rgb8" => (3, false),
            "bgr8" => (3, true),
            "rgba8" => (4, false),
            "bgra8" => (4, true),
            other => return Err(format!("colour image: encoding `{other}`; rgb8, bgr8, rgba8 or bgra8 expected")),
        };
        self.check(img, channels)?;
        let n = self.size();
        for (y, &row) in self.rows.iter().enumerate() {
            let line = &img.data[row as usize * img.step as usize..];
            for (x, &col) in self.cols.iter().enumerate() {
                let p = &line[col as usize * channels..][..3];
                let o = &mut out[(y * n + x) * 3..][..3];
                o.copy_from_slice(p);
                if swap {
                    o.swap(0, 2);
                }
            }
        }
        Ok(())
    }

    /// The aligned depth image as the policy's depth frame (`size²`, linear 0..10 m). A pixel
    /// the camera could not measure (0, NaN) reads as nearest: the safer mistake.
    pub fn depth(&self, img: &Image, out: &mut [u16]) -> Result<(), String> {
        let (metres, bytes) = depth_pixel(img)?;
        self.check(img, bytes)?;
        let n = self.size();
        for (y, &row) in self.rows.iter().enumerate() {
            let line = &img.data[row as usize * img.step as usize..];
            for (x, &col) in self.cols.iter().enumerate() {
                let m = metres(&line[col as usize * bytes..]);
                out[y * n + x] = if m.is_finite() && m > 0.0 { encode_depth(m) } else { 0 };
            }
        }
        Ok(())
    }

    fn check(&self, img: &Image, pixel_bytes: usize) -> Result<(), String> {
        if (img.width, img.height) != (self.width, self.height) {
            return Err(format!(
                "an image of {}×{}; camera_info says {}×{}",
                img.width, img.height, self.width, self.height
            ));
        }
        let need = img.step as usize * (img.height as usize - 1) + img.width as usize * pixel_bytes;
        if (img.step as usize) < img.width as usize * pixel_bytes || img.data.len() < need {
            return Err(format!(
                "an image of {}×{} `{}` with step {} holds {} bytes; {need} expected",
                img.width,
                img.height,
                img.encoding,
                img.step,
                img.data.len()
            ));
        }
        Ok(())
    }
}

/// How a depth image's pixel reads in metres, and its bytes: 16UC1 (mm) or 32FC1 (m),
/// little-endian; why not otherwise.
pub fn depth_pixel(img: &Image) -> Result<(fn(&[u8]) -> f32, usize), String> {
    let read: (fn(&[u8]) -> f32, usize) = match img.encoding.as_str() {
        "16UC1" | "mono16" => (|b| u16::from_le_bytes([b[0], b[1]]) as f32 / 1000.0, 2),
        "32FC1" => (|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]), 4),
        other => return Err(format!("depth image: encoding `{other}`; 16UC1 (mm) or 32FC1 (m) expected")),
    };
    if img.is_bigendian != 0 {
        return Err("depth image: big-endian; little-endian expected".into());
    }
    Ok(read)
}

/// The `camera_info` of an ideal pinhole camera of `width × height` whose vertical field of
/// view is `fov_deg` (how the simulator's camera is published).
pub fn pinhole(width: u32, height: u32, fov_deg: f64, header: super::msgs::Header) -> CameraInfo {
    let f = height as f64 / 2.0 / (fov_deg / 2.0).to_radians().tan();
    let (cx, cy) = ((width as f64 - 1.0) / 2.0, (height as f64 - 1.0) / 2.0);
    CameraInfo {
        header,
        height,
        width,
        distortion_model: "plumb_bob".into(),
        d: vec![0.0; 5],
        k: [f, 0.0, cx, 0.0, f, cy, 0.0, 0.0, 1.0],
        r: [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
        p: [f, 0.0, cx, 0.0, 0.0, f, cy, 0.0, 0.0, 0.0, 1.0, 0.0],
        binning_x: 0,
        binning_y: 0,
        roi: Default::default(),
    }
}

#[cfg(test)]
mod tests {
    use super::super::msgs::Header;
    use super::*;

    const VIEW: PolicyView = PolicyView { size: 64, fov_deg: 90.0 };

    fn image(w: u32, h: u32, encoding: &str, px: usize) -> Image {
        let data = (0..w as usize * h as usize * px).map(|i| (i % 251) as u8).collect();
        Image {
            header: Header::default(),
            height: h,
            width: w,
            encoding: encoding.into(),
            is_bigendian: 0,
            step: w * px as u32,
            data,
        }
    }

    /// What the policy reads of any per-pixel image (the simulator's instance ids) is picked
    /// where its colour is read.
    #[test]
    fn picking_reads_the_pixels_the_colour_reads() {
        let s = Sampling::new(&pinhole(640, 480, 90.0, Header::default()), VIEW).unwrap();
        let img = image(640, 480, "rgb8", 3);
        let mut rgb = vec![0; 64 * 64 * 3];
        s.colour(&img, &mut rgb).unwrap();
        let index: Vec<u32> = (0..640 * 480).collect();
        let picked: Vec<u32> = s.pick(&index).collect();
        assert_eq!(picked.len(), 64 * 64);
        for (p, px) in picked.iter().zip(rgb.chunks(3)) {
            assert_eq!(&img.data[*p as usize * 3..][..3], px);
        }
    }

    #[test]
    fn a_square_camera_at_the_policys_size_is_read_pixel_for_pixel() {
        let s = Sampling::new(&pinhole(64, 64, 90.0, Header::default()), VIEW).unwrap();
        let img = image(64, 64, "rgb8", 3);
        let mut out = vec![0; 64 * 64 * 3];
        s.colour(&img, &mut out).unwrap();
        assert_eq!(out, img.data);
    }

    #[test]
    fn the_simulators_640_by_480_serves_the_centre_square() {
        let info = pinhole(640, 480, 90.0, Header::default());
        let (h, v) = field_of_view(&info);
        assert!((v - 90.0).abs() < 1e-9 && (h - 106.26).abs() < 0.01, "{h} × {v}");
        let s = Sampling::new(&info, VIEW).unwrap();
        assert_eq!((s.cols[0], s.cols[63], s.rows[0], s.rows[63]), (83, 556, 3, 476));
    }

    #[test]
    fn a_narrower_camera_is_refused_in_one_line() {
        // a RealSense D435's colour camera: 69° × 42°
        let mut info = pinhole(640, 480, 42.0, Header::default());
        info.k[0] = 462.0;
        let e = Sampling::new(&info, VIEW).unwrap_err();
        assert!(e.contains("69.4° × 42.0°") && e.contains("90° × 90°") && !e.contains('\n'), "{e}");
    }

    #[test]
    fn bgr_is_swapped_and_other_encodings_refused() {
        let s = Sampling::new(&pinhole(64, 64, 90.0, Header::default()), VIEW).unwrap();
        let (rgb, mut bgr) = (image(64, 64, "rgb8", 3), image(64, 64, "bgr8", 3));
        for p in bgr.data.chunks_mut(3) {
            p.swap(0, 2);
        }
        let (mut a, mut b) = (vec![0; 64 * 64 * 3], vec![0; 64 * 64 * 3]);
        s.colour(&rgb, &mut a).unwrap();
        s.colour(&bgr, &mut b).unwrap();
        assert_eq!(a, b);
        let e = s.colour(&image(64, 64, "mono8", 1), &mut a).unwrap_err();
        assert!(e.contains("`mono8`"), "{e}");
        let e = s.colour(&image(32, 64, "rgb8", 3), &mut a).unwrap_err();
        assert!(e.contains("32×64"), "{e}");
        let mut short = image(64, 64, "rgb8", 3);
        short.data.truncate(100);
        assert!(s.colour(&short, &mut a).unwrap_err().contains("holds 100 bytes"));
    }

    #[test]
    fn depth_in_millimetres_and_metres_reads_the_same_and_holes_read_near() {
        let s = Sampling::new(&pinhole(64, 64, 90.0, Header::default()), VIEW).unwrap();
        let mm: Vec<u16> = (0..64 * 64).map(|i| if i == 5 { 0 } else { 500 + (i % 3000) as u16 }).collect();
        let mut a = image(64, 64, "16UC1", 2);
        a.data = mm.iter().flat_map(|v| v.to_le_bytes()).collect();
        let mut b = image(64, 64, "32FC1", 4);
        b.data = mm.iter().flat_map(|&v| (if v == 0 { f32::NAN } else { v as f32 / 1000.0 }).to_le_bytes()).collect();
        let (mut da, mut db) = (vec![1; 64 * 64], vec![2; 64 * 64]);
        s.depth(&a, &mut da).unwrap();
        s.depth(&b, &mut db).unwrap();
        assert_eq!(da, db);
        assert_eq!(da[5], 0);
        assert_eq!(da[6], encode_depth(0.506));
        let e = s.depth(&image(64, 64, "rgb8", 3), &mut da).unwrap_err();
        assert!(e.contains("16UC1 (mm) or 32FC1 (m)"), "{e}");
    }
}

//! `tricons devices`: the V4L2 video nodes of this machine, their formats and frame sizes.

use anyhow::Result;

/// Arguments of `tricons devices`.
#[derive(clap::Args)]
#[command(after_help = "Lists every /dev/video* node (Linux, V4L2): its card, driver and bus, and for \
    capture nodes each pixel format with its frame sizes, marking the formats tricons decodes \
    (YUYV, MJPG, RGB3 colour; Z16 depth) as \"(supported)\". Nodes that are busy or unreadable are \
    listed with the reason. With no /dev/video* node it says so on stderr and exits 0.\n\n\
    Examples:\n  tricons devices\n  tricons devices --json > devices.json")]
pub struct Args {
    /// Print the list as JSON (an array of nodes with their formats and frame sizes).
    #[arg(long)]
    json: bool,
}

/// The line printed when there is no node at all.
#[cfg(all(feature = "v4l", target_os = "linux"))]
const NO_DEVICES: &str = "no V4L2 capture devices found (no /dev/video* nodes): \
    is the camera plugged in and the uvcvideo module loaded?";

#[cfg(all(feature = "v4l", target_os = "linux"))]
pub fn run(args: Args) -> Result<()> {
    use std::io::Write;
    use tricons::capture::v4l2::list_devices;

    let devices = list_devices()?;
    let stdout = std::io::stdout();
    let mut out = std::io::BufWriter::new(stdout.lock());
    if args.json {
        writeln!(out, "{}", serde_json::to_string_pretty(&devices)?)?;
    } else {
        for dev in &devices {
            write!(out, "{}", dev.path.display())?;
            if !dev.card.is_empty() || !dev.driver.is_empty() {
                write!(out, "  {} (driver {}, bus {})", dev.card, dev.driver, dev.bus)?;
            }
            if let Some(err) = &dev.error {
                write!(out, "  error: {err}")?;
            } else if !dev.capture {
                write!(out, "  not a video capture node (metadata or output)")?;
            }
            writeln!(out)?;
            for format in &dev.formats {
                let supported = if format.known.is_some() { "  (supported)" } else { "" };
                writeln!(out, "  {}  {}{supported}", format.fourcc, format.description)?;
                if !format.sizes.is_empty() {
                    let sizes: Vec<String> = format.sizes.iter().map(ToString::to_string).collect();
                    writeln!(out, "        {}", sizes.join(", "))?;
                }
            }
        }
    }
    out.flush()?;
    if devices.is_empty() {
        eprintln!("{NO_DEVICES}");
    } else if !devices.iter().any(|d| d.capture) {
        eprintln!("none of the {} /dev/video* nodes is a video capture node", devices.len());
    }
    Ok(())
}

#[cfg(not(all(feature = "v4l", target_os = "linux")))]
pub fn run(_args: Args) -> Result<()> {
    anyhow::bail!(
        "capture support is not compiled in: V4L2 capture needs Linux and the `v4l` feature \
         (rebuild with default features)"
    )
}

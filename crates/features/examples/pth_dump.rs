//! Lists a checkpoint's tensors: name, shape, sum and sum of squares (to compare with PyTorch).
//!
//! `cargo run -p jointloc-features --example pth_dump -- weights.pth`

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let path = std::env::args().nth(1).ok_or("usage: pth_dump FILE")?;
    let sd = jointloc_features::pth::StateDict::read(std::path::Path::new(&path))?;
    for name in sd.names() {
        let t = sd.get(name)?;
        let sum: f64 = t.data.iter().map(|&x| f64::from(x)).sum();
        let sq: f64 = t.data.iter().map(|&x| f64::from(x) * f64::from(x)).sum();
        println!("{name} {:?} {sum:.6e} {sq:.6e}", t.shape);
    }
    Ok(())
}

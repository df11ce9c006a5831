//! `cargo bench --bench reshade -- --model models/<dir> [--size 640x384] [--views 48]
//! [--engines tract,ort] [--precisions fp32,fp16,int8] [--threads 2] [--timed-views 8]`
//! prints the reshading benchmark tables (see `reshader::eval::reshade`).

fn main() {
    env_logger::Builder::from_env(env_logger::Env::default().default_filter_or("warn")).init();
    let args: Vec<String> = std::env::args().skip(1).collect();
    let report = reshader::eval::reshade::BenchConfig::from_args(&args)
        .and_then(|config| reshader::eval::reshade::run(&config));
    match report {
        Ok(text) => println!("{text}"),
        Err(e) => {
            eprintln!("reshade benchmark: {e}");
            std::process::exit(2);
        }
    }
}

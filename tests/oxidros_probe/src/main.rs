//! A ROS 2 node on rmw_zenoh's wire format, written with oxidros-zenoh (not with zensim's code), so
//! the tests can check that `zensim ros2` speaks the format another implementation speaks.
//!
//! Usage (the router comes from ZENOH_SESSION_CONFIG_URI, the domain from ROS_DOMAIN_ID):
//!   zensim-oxidros-probe echo TOPIC COUNT TIMEOUT_S
//!       subscribes sensor_msgs/JointState on TOPIC, prints COUNT messages as JSON lines
//!       ({"sec":..,"nanosec":..,"name":[..],"position":[..]}), then the graph as one JSON line
//!       ({"nodes":[..],"topics":[[name, type],..]}); exits 1 when none came within TIMEOUT_S.
//!   zensim-oxidros-probe forward TOPIC V1,V2,... RATE_HZ DURATION_S
//!       publishes std_msgs/Float64MultiArray with data V1,V2,... on TOPIC.
use std::time::{Duration, Instant};

use oxidros_msg::common_interfaces::sensor_msgs::msg::JointState;
use oxidros_msg::common_interfaces::std_msgs::msg::Float64MultiArray;
use oxidros_msg::msg::F64Seq;
use oxidros_zenoh::{Context, DurabilityPolicy, Profile};

/// oxidros-zenoh 0.5.9 with zenoh-ext 1.10 refuses VOLATILE subscribers ("max_samples must not be
/// zero"); TRANSIENT_LOCAL matches a volatile publisher too in rmw_zenoh.
fn profile() -> Profile {
    Profile { durability: DurabilityPolicy::TransientLocal, depth: 10, ..Default::default() }
}

fn json_str(s: &str) -> String {
    format!("\"{}\"", s.replace('\\', "\\\\").replace('"', "\\\""))
}

fn json_f64s(values: &[f64]) -> String {
    let items: Vec<String> = values.iter().map(|v| format!("{v:?}")).collect();
    format!("[{}]", items.join(","))
}

async fn echo(topic: &str, count: usize, timeout_s: f64) -> i32 {
    let ctx = Context::new().expect("zenoh session");
    let node = ctx.z_create_node("oxidros_probe", None).expect("node");
    let mut sub = node.z_create_subscriber::<JointState>(topic, Some(profile())).expect("subscriber");
    let deadline = Instant::now() + Duration::from_secs_f64(timeout_s);
    let mut seen = 0;
    while seen < count {
        let left = deadline.saturating_duration_since(Instant::now());
        match tokio::time::timeout(left, sub.z_recv()).await {
            Ok(Ok(msg)) => {
                let names: Vec<String> = msg.name.iter().map(|n| json_str(&n.get_string())).collect();
                println!(
                    "{{\"sec\":{},\"nanosec\":{},\"name\":[{}],\"position\":{}}}",
                    msg.header.stamp.sec,
                    msg.header.stamp.nanosec,
                    names.join(","),
                    json_f64s(msg.position.as_slice())
                );
                seen += 1;
            }
            Ok(Err(e)) => eprintln!("receive error: {e}"),
            Err(_) => break,
        }
    }
    let graph = ctx.graph_cache();
    let nodes: Vec<String> = graph.get_node_names().iter().map(|n| json_str(n)).collect();
    let topics: Vec<String> = graph
        .get_topic_names_and_types()
        .iter()
        .map(|(n, t)| format!("[{},{}]", json_str(n), json_str(t)))
        .collect();
    println!("{{\"nodes\":[{}],\"topics\":[{}]}}", nodes.join(","), topics.join(","));
    if seen == 0 { 1 } else { 0 }
}

async fn forward(topic: &str, values: &[f64], rate_hz: f64, duration_s: f64) -> i32 {
    let ctx = Context::new().expect("zenoh session");
    let node = ctx.z_create_node("oxidros_commander", None).expect("node");
    let publisher = node.z_create_publisher::<Float64MultiArray>(topic, Some(profile())).expect("publisher");
    let end = Instant::now() + Duration::from_secs_f64(duration_s);
    let mut sent = 0;
    while Instant::now() < end {
        let mut msg = Float64MultiArray::new().expect("message");
        let mut data = F64Seq::<0>::new(values.len()).expect("sequence");
        data.as_mut_slice().copy_from_slice(values);
        msg.data = data;
        if let Err(e) = publisher.z_send(&msg) {
            eprintln!("send error: {e}");
            return 1;
        }
        sent += 1;
        tokio::time::sleep(Duration::from_secs_f64(1.0 / rate_hz)).await;
    }
    println!("{{\"sent\":{sent}}}");
    0
}

#[tokio::main]
async fn main() {
    let args: Vec<String> = std::env::args().collect();
    let code = match args.get(1).map(String::as_str) {
        Some("echo") if args.len() == 5 => {
            echo(&args[2], args[3].parse().expect("COUNT"), args[4].parse().expect("TIMEOUT_S")).await
        }
        Some("forward") if args.len() == 6 => {
            let values: Vec<f64> =
                args[3].split(',').map(|v| v.parse().expect("V1,V2,...")).collect();
            forward(&args[2], &values, args[4].parse().expect("RATE_HZ"), args[5].parse().expect("DURATION_S")).await
        }
        _ => {
            eprintln!("usage: zensim-oxidros-probe echo TOPIC COUNT TIMEOUT_S | forward TOPIC V1,V2,... RATE_HZ DURATION_S");
            2
        }
    };
    std::process::exit(code);
}

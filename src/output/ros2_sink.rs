//! Results on ROS 2 topics over DDS (ros2-client on RustDDS, pure Rust): per frame a
//! `vision_msgs/Detection3DArray` (default `/tricons/detections`) and a
//! `visualization_msgs/MarkerArray` for RViz (default `/tricons/markers`).
//!
//! **Loopback by default.** The participant uses only 127.0.0.1: it advertises only loopback
//! locators and, Linux's `lo` having no multicast flag, joins and sends no multicast;
//! discovery goes by unicast to the well-known ports of 127.0.0.1. Naming an interface
//! ([`Ros2Config::interface`], `--ros2-interface`) opens discovery and data to that network
//! (logged at WARN). RustDDS binds its sockets to all addresses either way: loopback-only
//! decides what is announced and sent, it is not a firewall.

use super::predictions::FramePredictions;
use super::sink::Sink;
use crate::error::{Error, Result};
use crate::ros2::convert;
use crate::ros2::msg::{Detection3DArray, MarkerArray};
use ros2_client::qos::{Durability, History, Reliability, WhenFull};
use ros2_client::{Context, MessageTypeName, Name, Node, NodeName, NodeOptions, Publisher, QosProfile};
use serde::{Deserialize, Serialize};
use std::net::{IpAddr, Ipv4Addr};

/// Default topic of the detections.
pub const DEFAULT_DETECTIONS_TOPIC: &str = "/tricons/detections";
/// Default topic of the markers.
pub const DEFAULT_MARKERS_TOPIC: &str = "/tricons/markers";
/// Name of the node (in namespace `/`).
pub const NODE_NAME: &str = "tricons";

/// Delivery guarantee of the topics.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "snake_case")]
pub enum Ros2Reliability {
    /// Resend until acknowledged (a publish waits at most 100 ms for a full send window).
    #[default]
    Reliable,
    /// Send once (what camera drivers use for images).
    BestEffort,
}

/// Whether late subscribers get earlier samples.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "snake_case")]
pub enum Ros2Durability {
    /// Only samples published after they joined.
    #[default]
    Volatile,
    /// The last `depth` samples too (subscribers must ask for transient_local).
    TransientLocal,
}

/// QoS of the published topics.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Ros2Qos {
    /// Reliable or best effort.
    pub reliability: Ros2Reliability,
    /// Volatile or transient local.
    pub durability: Ros2Durability,
    /// History depth (KEEP_LAST).
    pub depth: usize,
}

impl Default for Ros2Qos {
    fn default() -> Ros2Qos {
        Ros2Qos { reliability: Ros2Reliability::Reliable, durability: Ros2Durability::Volatile, depth: 10 }
    }
}

impl Ros2Qos {
    fn profile(&self) -> QosProfile {
        QosProfile::publisher_default()
            .reliability(match self.reliability {
                Ros2Reliability::Reliable => Reliability::Reliable { when_full: WhenFull::DEFAULT },
                Ros2Reliability::BestEffort => Reliability::BestEffort,
            })
            .durability(match self.durability {
                Ros2Durability::Volatile => Durability::Volatile,
                Ros2Durability::TransientLocal => Durability::TransientLocal,
            })
            .history(History::KeepLast { depth: self.depth.max(1) })
    }
}

/// Where and how results are published.
#[derive(Clone, Debug, PartialEq)]
pub struct Ros2Config {
    /// DDS domain (`ROS_DOMAIN_ID`).
    pub domain_id: u16,
    /// Topic of the `Detection3DArray`s.
    pub detections_topic: String,
    /// Topic of the `MarkerArray`s (`None`: no markers).
    pub markers_topic: Option<String>,
    /// A network interface (name such as `eth0`, or one of its IPv4 addresses) to publish on
    /// besides loopback; `None`: loopback only.
    pub interface: Option<String>,
    /// QoS of both topics.
    pub qos: Ros2Qos,
    /// `frame_id` of the headers (the colour camera's optical frame).
    pub frame_id: String,
}

impl Default for Ros2Config {
    fn default() -> Ros2Config {
        Ros2Config {
            domain_id: 0,
            detections_topic: DEFAULT_DETECTIONS_TOPIC.into(),
            markers_topic: Some(DEFAULT_MARKERS_TOPIC.into()),
            interface: None,
            qos: Ros2Qos::default(),
            frame_id: crate::capture::DEFAULT_FRAME_ID.into(),
        }
    }
}

/// The IPv4 addresses DDS may use: loopback, and the named interface's (looked up in
/// `interfaces`, the machine's).
pub fn resolve_networks(interface: Option<&str>, interfaces: &[netdev::Interface]) -> Result<Vec<IpAddr>> {
    let mut addrs = vec![IpAddr::V4(Ipv4Addr::LOCALHOST)];
    let Some(name) = interface else {
        return Ok(addrs);
    };
    if let Ok(ip) = name.parse::<IpAddr>() {
        addrs.push(ip);
        return Ok(addrs);
    }
    let Some(found) = interfaces.iter().find(|i| i.name == name) else {
        let names: Vec<&str> = interfaces.iter().map(|i| i.name.as_str()).collect();
        return Err(Error::InvalidArgument(format!(
            "--ros2-interface {name}: no such network interface (this machine has {})",
            names.join(", ")
        )));
    };
    if found.ipv4.is_empty() {
        return Err(Error::InvalidArgument(format!("--ros2-interface {name}: the interface has no IPv4 address")));
    }
    addrs.extend(found.ipv4.iter().map(|net| IpAddr::V4(net.addr())));
    Ok(addrs)
}

/// Publishes each frame's results on ROS 2 topics (see the module docs).
pub struct Ros2Sink {
    // field order is drop order: publishers before the node before the context
    detections: Publisher<Detection3DArray>,
    markers: Option<Publisher<MarkerArray<'static>>>,
    _node: Node,
    _context: Context,
    config: Ros2Config,
    networks: Vec<IpAddr>,
    /// Samples not sent (a reliable writer whose subscribers did not take them in time).
    dropped: u64,
}

fn dds_error(what: &str, e: impl std::fmt::Display) -> Error {
    Error::InvalidArgument(format!("ROS 2 {what}: {e}"))
}

impl Ros2Sink {
    /// Joins the DDS domain and creates the publishers.
    pub fn start(config: Ros2Config) -> Result<Ros2Sink> {
        let interfaces = netdev::get_interfaces();
        let networks = resolve_networks(config.interface.as_deref(), &interfaces)?;
        if interfaces.iter().any(|i| i.is_loopback() && i.is_multicast()) {
            log::warn!(
                "ros2: the loopback interface has the MULTICAST flag: RustDDS also sends its discovery \
                 by multicast on it (the packets stay on this machine)"
            );
        }
        if let Some(name) = &config.interface {
            log::warn!("ros2: discovery and data also on {name} ({:?}): reachable from that network", &networks[1..]);
        }
        let participant = ros2_client::dds::rustdds::DomainParticipantBuilder::new(config.domain_id)
            .with_only_networks(networks.iter().copied())
            .build()
            .map_err(|e| dds_error("participant", e))?;
        let context = Context::from_domain_participant(participant).map_err(|e| dds_error("context", e))?;
        let name = NodeName::new("/", NODE_NAME).map_err(|e| dds_error("node name", e))?;
        let mut node =
            context.new_node(name, NodeOptions::new().enable_rosout(false)).map_err(|e| dds_error("node", e))?;
        let qos = config.qos.profile();
        let topic_name = |t: &str| Name::parse(t).map_err(|e| dds_error(&format!("topic name {t:?}"), e));
        let topic = node
            .create_topic(
                &topic_name(&config.detections_topic)?,
                MessageTypeName::new("vision_msgs", "Detection3DArray"),
                &qos,
            )
            .map_err(|e| dds_error("topic", e))?;
        let detections = node.create_publisher(&topic, None).map_err(|e| dds_error("publisher", e))?;
        let markers = match &config.markers_topic {
            Some(t) => {
                let topic = node
                    .create_topic(&topic_name(t)?, MessageTypeName::new("visualization_msgs", "MarkerArray"), &qos)
                    .map_err(|e| dds_error("topic", e))?;
                Some(node.create_publisher(&topic, None).map_err(|e| dds_error("publisher", e))?)
            }
            None => None,
        };
        Ok(Ros2Sink { detections, markers, _node: node, _context: context, config, networks, dropped: 0 })
    }
}

impl Sink for Ros2Sink {
    fn describe(&self) -> String {
        format!(
            "ROS 2 {}{} (domain {}, {:?})",
            self.config.detections_topic,
            self.config.markers_topic.as_ref().map(|m| format!(" + {m}")).unwrap_or_default(),
            self.config.domain_id,
            self.networks
        )
    }

    /// A sample DDS does not take (a reliable subscriber too slow to acknowledge within
    /// 100 ms) is dropped and counted, not an error: a slow robot must not stop the service.
    fn publish(&mut self, frame: &FramePredictions, _line: &str) -> Result<()> {
        let frame_id = &self.config.frame_id;
        let mut failures = Vec::new();
        if let Err(e) = self.detections.publish(convert::detections(frame, frame_id)) {
            failures.push(format!("{}: {e}", self.config.detections_topic));
        }
        if let (Some(markers), Some(topic)) = (&self.markers, &self.config.markers_topic)
            && let Err(e) = markers.publish(convert::markers(frame, frame_id))
        {
            failures.push(format!("{topic}: {e}"));
        }
        for failure in failures {
            self.dropped += 1;
            if self.dropped == 1 || self.dropped.is_multiple_of(100) {
                log::warn!(
                    "ros2: frame {} not sent on {failure} ({} samples dropped so far)",
                    frame.frame,
                    self.dropped
                );
            }
        }
        Ok(())
    }

    fn flush(&mut self) -> Result<()> {
        Ok(())
    }
}
